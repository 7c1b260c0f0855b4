#pragma once
// SE(3) of camera tracking and pose-graph optimisation. Twists are ordered
// (v, w): translation part first, then rotation, as in the LCM messages
// (tx ty tz rx ry rz), and exp(xi) * p ~ p + v + w x p for small xi.
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rekon/common/pose.hpp"

namespace rekon {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

// [v]x: skew(v) * p = v x p. Inline: the pose graph's Jacobians call it per edge.
inline Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d s;
  s << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return s;
}

Pose expSe3(const Vector6d& xi);
Vector6d logSe3(const Pose& pose);
// Adjoint of `pose` on (v, w) twists: pose * exp(xi) = exp(adjoint(pose) * xi) * pose.
Matrix6d adjoint(const Pose& pose);

}  // namespace rekon
