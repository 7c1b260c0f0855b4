#include "rekon/common/pose.hpp"

#include <fmt/format.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <sstream>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"
#include "rekon/common/pose_text.hpp"

namespace rekon {

bool isValidPose(const Pose& pose, double tolerance) {
  if (!pose.matrix().allFinite()) return false;
  const Eigen::Matrix3d r = pose.linear();
  if ((r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > tolerance) return false;
  return std::abs(r.determinant() - 1.0) <= tolerance;
}

void requireValidPose(const Pose& pose, const std::string& what) {
  if (!pose.matrix().allFinite()) throw Error(what + ": pose has NaN or infinite entries; fix the source of the pose");
  if (!isValidPose(pose, 1e-4)) throw Error(what + ": pose rotation is not orthonormal; normalise the quaternion or rotation matrix");
}

Pose poseFromQuatTrans(const Eigen::Quaterniond& q, const Eigen::Vector3d& t) {
  Pose p = Pose::Identity();
  p.linear() = q.normalized().toRotationMatrix();
  p.translation() = t;
  return p;
}

Pose orthonormalised(const Pose& pose) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(pose.linear(), Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d r = svd.matrixU() * svd.matrixV().transpose();
  if (r.determinant() < 0) {
    Eigen::Matrix3d u = svd.matrixU();
    u.col(2) *= -1;
    r = u * svd.matrixV().transpose();
  }
  Pose out = pose;
  out.linear() = r;
  return out;
}

Pose movedWithGraph(const Pose& anchor_graph, const Pose& anchor_odometry, const Pose& odometry) {
  return orthonormalised(anchor_graph * anchor_odometry.inverse() * odometry);
}

double translationDistance(const Pose& a, const Pose& b) { return (a.translation() - b.translation()).norm(); }

double rotationAngle(const Pose& a, const Pose& b) {
  const Eigen::Matrix3d r = a.linear().transpose() * b.linear();
  const double c = std::clamp((r.trace() - 1.0) * 0.5, -1.0, 1.0);
  return std::acos(c);
}

Trajectory readTumTrajectory(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open trajectory; check the path");
  Trajectory out;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream ss(line);
    double v[8];
    for (double& x : v) {
      if (!(ss >> x)) {
        throw Error(path + ":" + std::to_string(line_no) + ": expected 'timestamp tx ty tz qx qy qz qw'; fix the line");
      }
    }
    for (double x : v) {
      if (!std::isfinite(x)) throw Error(path + ":" + std::to_string(line_no) + ": NaN or infinite value; fix the line");
    }
    const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
    if (std::abs(q.norm() - 1.0) > 1e-2) {
      throw Error(path + ":" + std::to_string(line_no) + ": quaternion norm " + std::to_string(q.norm()) + " is not 1; fix the line");
    }
    out.push_back({v[0], poseFromQuatTrans(q, Eigen::Vector3d(v[1], v[2], v[3]))});
  }
  return out;
}

std::string poseText(const Pose& pose) {
  const Eigen::Quaterniond q(pose.linear());
  const Eigen::Vector3d t = pose.translation();
  return fmt::format("{:.9f} {:.9f} {:.9f} {:.9f} {:.9f} {:.9f} {:.9f}", t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w());
}

void writeTumTrajectory(const Trajectory& trajectory, const std::string& path) {
  std::ostringstream out;
  out << "# timestamp tx ty tz qx qy qz qw\n" << std::fixed << std::setprecision(6);
  for (const auto& s : trajectory) out << s.timestamp << ' ' << poseText(s.pose) << '\n';
  writeFileAtomically(path, out.str());  // a kill mid-write leaves the previous file whole
}

int nearestInTime(const Trajectory& trajectory, double timestamp, double max_difference) {
  // Trajectories are sorted by time in practice, but a linear scan keeps this
  // correct for any order; callers cache results when it matters.
  int best = -1;
  double best_d = max_difference;
  for (size_t i = 0; i < trajectory.size(); ++i) {
    const double d = std::abs(trajectory[i].timestamp - timestamp);
    if (d <= best_d) {
      best_d = d;
      best = static_cast<int>(i);
    }
  }
  return best;
}

}  // namespace rekon
