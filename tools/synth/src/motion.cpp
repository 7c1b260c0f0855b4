#include "motion.hpp"

#include <cmath>
#include <numbers>

#include "sensor_noise.hpp"

namespace rekon::synth {

Pose lookPose(const Eigen::Vector3d& position, double yaw, double pitch, double roll) {
  const Eigen::Vector3d forward(std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw), std::sin(pitch));
  const Eigen::Vector3d right0(std::sin(yaw), -std::cos(yaw), 0.0);
  const Eigen::Vector3d down0 = forward.cross(right0);
  const Eigen::Vector3d right = std::cos(roll) * right0 + std::sin(roll) * down0;
  const Eigen::Vector3d down = forward.cross(right);
  Pose pose = Pose::Identity();
  pose.linear().col(0) = right;
  pose.linear().col(1) = down;
  pose.linear().col(2) = forward;
  pose.translation() = position;
  return orthonormalised(pose);
}

Shake::Shake(uint64_t seed, double period_s, double translation_rms_m, double rotation_rms_rad, double min_hz,
             double max_hz, int harmonics_per_axis) {
  Rng rng(mixSeed(seed, 0x5EA4Eull));
  const int k_min = std::max(1, static_cast<int>(std::ceil(min_hz * period_s)));
  const int k_max = std::max(k_min, static_cast<int>(std::floor(max_hz * period_s)));
  for (int axis = 0; axis < 6; ++axis) {
    const double rms = axis < 3 ? translation_rms_m : rotation_rms_rad;
    double power = 0.0;
    for (int i = 0; i < harmonics_per_axis; ++i) {
      const int k = k_min + static_cast<int>(rng.uniform() * (k_max - k_min + 1));
      const double omega = 2.0 * std::numbers::pi * std::min(k, k_max) / period_s;
      // Amplitude falling with frequency, like the tremor of a hand.
      const double amplitude = (0.5 + rng.uniform()) / (omega / (2.0 * std::numbers::pi));
      axes_[axis].push_back({omega, amplitude, 2.0 * std::numbers::pi * rng.uniform()});
      power += 0.5 * amplitude * amplitude;
    }
    const double scale = power > 0 ? rms / std::sqrt(power) : 0.0;
    for (auto& h : axes_[axis]) h.amplitude *= scale;
  }
}

void Shake::at(double t, Eigen::Vector3d* translation, Eigen::Vector3d* rotation) const {
  double v[6];
  for (int axis = 0; axis < 6; ++axis) {
    v[axis] = 0.0;
    for (const auto& h : axes_[axis]) v[axis] += h.amplitude * std::sin(h.omega * t + h.phase);
  }
  *translation = Eigen::Vector3d(v[0], v[1], v[2]);
  *rotation = Eigen::Vector3d(v[3], v[4], v[5]);
}

}  // namespace rekon::synth
