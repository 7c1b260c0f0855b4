#pragma once
// Conversions between rekon types and the generated LCM message types, with
// validation of everything that arrives from outside (NaN poses, bad
// intrinsics, impossible sizes).
#include <Eigen/Core>
#include <optional>
#include <string>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/pose_t.hpp"

namespace rekon {

rekon_msgs::pose_t toMsg(const Pose& pose);
// nullopt when the message holds NaN/inf or a quaternion far from unit norm.
std::optional<Pose> fromMsg(const rekon_msgs::pose_t& msg);

void toArray(const Eigen::Matrix<double, 6, 6>& m, double out[36]);
// nullopt when an entry is not finite.
std::optional<Eigen::Matrix<double, 6, 6>> matrix6FromArray(const double in[36]);

void setIntrinsics(const Intrinsics& k, rekon_msgs::frame_t* msg);
// Throws rekon::Error for NaN/inf, non-positive or absurd values.
Intrinsics intrinsicsOf(const rekon_msgs::frame_t& msg);

}  // namespace rekon
