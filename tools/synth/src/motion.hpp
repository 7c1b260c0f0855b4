#pragma once
// Building blocks of hand-held camera motion: a camera pose from heading,
// pitch and roll, and a seeded "shake" (a sum of sinusoids in the 1-5 Hz band
// of a hand-held camera) that is exactly periodic over a chosen period so a
// looping trajectory still returns to its start.
#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "rekon/common/pose.hpp"

namespace rekon::synth {

// Camera-to-world pose in a z-up world: the camera looks along heading `yaw`
// (radians from +x towards +y), tilted up by `pitch`, rolled by `roll`
// (camera axes: x right, y down, z forward).
Pose lookPose(const Eigen::Vector3d& position, double yaw, double pitch, double roll);

class Shake {
 public:
  // Harmonics of 1/period_s between min_hz and max_hz; rms amplitudes in
  // metres and radians per axis.
  Shake(uint64_t seed, double period_s, double translation_rms_m, double rotation_rms_rad, double min_hz = 0.7,
        double max_hz = 4.5, int harmonics_per_axis = 6);
  // Offsets at time t: translation (metres) and small rotation (radians, as yaw, pitch, roll).
  void at(double t, Eigen::Vector3d* translation, Eigen::Vector3d* rotation) const;

 private:
  struct Harmonic {
    double omega, amplitude, phase;
  };
  std::vector<Harmonic> axes_[6];
};

// Frame timestamps: i / 30.
constexpr double kFrameRateHz = 30.0;

}  // namespace rekon::synth
