#pragma once
// The few SE(3) operations the tracker needs. Twists are ordered (v, w):
// translation part first, then rotation, as in the LCM messages
// (tx ty tz rx ry rz), and exp(xi) * p ~ p + v + w x p for small xi.
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rekon/common/pose.hpp"

namespace rekon::tracker {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

Eigen::Matrix3d skew(const Eigen::Vector3d& v);
Pose expSe3(const Vector6d& xi);
Vector6d logSe3(const Pose& pose);
// Adjoint of `pose` on (v, w) twists: pose * exp(xi) = exp(adjoint(pose) * xi) * pose.
Matrix6d adjoint(const Pose& pose);

}  // namespace rekon::tracker
