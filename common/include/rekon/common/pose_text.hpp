#pragma once
// A pose as text the way TUM trajectories, rekon's session files and g2o
// write it: "tx ty tz qx qy qz qw", 9 decimals (a nanometre, 1e-9 of a unit
// quaternion).
#include <string>

#include "rekon/common/pose.hpp"

namespace rekon {

std::string poseText(const Pose& pose);

}  // namespace rekon
