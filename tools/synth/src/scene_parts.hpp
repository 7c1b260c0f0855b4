#pragma once
// What the scene definitions share: the material palette, shells, tables,
// sampling a trajectory at 30 Hz and adding hand shake to a pose.
#include <functional>
#include <numbers>
#include <vector>

#include "geometry.hpp"
#include "motion.hpp"
#include "texture.hpp"

namespace rekon::synth::parts {

constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;

// Palette shared by the scenes.
enum Mat { kWallWarm, kWallCool, kFloor, kCeiling, kWood, kRed, kGreen, kBlue, kYellow, kMetal, kPurple, kPoster };
std::vector<Material> palette();

Shell shell(V3 lo, V3 hi, int mx0, int mx1, int my0, int my1, int floor, int ceiling);
// A table: top of half size (hx, hy) at height `height`, four legs.
void addTable(std::vector<Primitive>* out, float x, float y, float hx, float hy, float height, float yaw, int mat);
// Poses at i / 30 s for i < frames.
Trajectory sample(int frames, const std::function<Pose(double)>& pose_at);
Pose shaken(const Shake& shake, double t, const Eigen::Vector3d& position, double yaw, double pitch, double roll);

}  // namespace rekon::synth::parts
