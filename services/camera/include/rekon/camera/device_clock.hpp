#pragma once
// Maps a device's own frame timestamps onto the host's wall clock. A frame
// reaches the host after a delay that varies (USB, driver, scheduling); the
// device stamps it when its sensor exposed it, at a steady rate. So the
// offset host - device is estimated by its lower envelope (the least delayed
// frame is the closest to the truth), allowed to rise by kMaxDriftPpm so that
// a device clock slower than the host's is followed, and re-anchored when the
// device time jumps (a recording restarts, a device resets) or the stamp
// would be off the arrival time by more than kMaxDelayS. The result: stamps
// as steady as the device's, on the host's clock (what trajectories and
// recordings carry), never later than the arrival.
#include <optional>

namespace rekon::camera {

// The host's wall clock in seconds since the epoch: what every captured
// frame is stamped with (trajectories and recordings carry it).
double hostWallSeconds();

class DeviceClock {
 public:
  static constexpr double kMaxDriftPpm = 200.0;
  static constexpr double kMaxDelayS = 0.5;

  // `device_s`: the device's timestamp in seconds; `arrival_s`: host wall
  // clock when the frame arrived. Returns the frame's host timestamp.
  double stamp(double device_s, double arrival_s);
  int resets() const { return resets_; }

 private:
  std::optional<double> offset_;  // host - device, seconds
  double last_device_s_ = 0.0;
  int resets_ = 0;
};

}  // namespace rekon::camera
