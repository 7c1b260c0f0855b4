#include "rekon/common/se3.hpp"

#include <cmath>

namespace rekon {

Pose expSe3(const Vector6d& xi) {
  const Eigen::Vector3d v = xi.head<3>();
  const Eigen::Vector3d w = xi.tail<3>();
  const double theta = w.norm();
  const Eigen::Matrix3d wx = skew(w);
  Eigen::Matrix3d r, vmat;
  if (theta < 1e-8) {
    // Series expansion: exact to second order, avoids 0/0.
    r = Eigen::Matrix3d::Identity() + wx + 0.5 * wx * wx;
    vmat = Eigen::Matrix3d::Identity() + 0.5 * wx + wx * wx / 6.0;
  } else {
    const double a = std::sin(theta) / theta;
    const double b = (1.0 - std::cos(theta)) / (theta * theta);
    const double c = (theta - std::sin(theta)) / (theta * theta * theta);
    r = Eigen::Matrix3d::Identity() + a * wx + b * wx * wx;
    vmat = Eigen::Matrix3d::Identity() + b * wx + c * wx * wx;
  }
  Pose out = Pose::Identity();
  out.linear() = r;
  out.translation() = vmat * v;
  return out;
}

Vector6d logSe3(const Pose& pose) {
  const Eigen::AngleAxisd aa(pose.linear());
  const Eigen::Vector3d w = aa.angle() * aa.axis();
  const double theta = aa.angle();
  const Eigen::Matrix3d wx = skew(w);
  Eigen::Matrix3d vinv;
  if (theta < 1e-8) {
    vinv = Eigen::Matrix3d::Identity() - 0.5 * wx + wx * wx / 12.0;
  } else {
    const double half = 0.5 * theta;
    const double k = (1.0 - half * std::cos(half) / std::sin(half)) / (theta * theta);
    vinv = Eigen::Matrix3d::Identity() - 0.5 * wx + k * wx * wx;
  }
  Vector6d xi;
  xi.head<3>() = vinv * pose.translation();
  xi.tail<3>() = w;
  return xi;
}

Matrix6d adjoint(const Pose& pose) {
  Matrix6d a = Matrix6d::Zero();
  const Eigen::Matrix3d r = pose.linear();
  a.topLeftCorner<3, 3>() = r;
  a.topRightCorner<3, 3>() = skew(pose.translation()) * r;
  a.bottomRightCorner<3, 3>() = r;
  return a;
}

}  // namespace rekon
