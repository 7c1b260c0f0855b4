#include "rekon/camera/device_clock.hpp"

#include <algorithm>
#include <chrono>

namespace rekon::camera {

double hostWallSeconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

double DeviceClock::stamp(double device_s, double arrival_s) {
  const double observed = arrival_s - device_s;
  const bool jumped = offset_ && (device_s < last_device_s_ || device_s - last_device_s_ > 10.0);
  if (!offset_ || jumped || observed - *offset_ > kMaxDelayS) {
    if (offset_) ++resets_;
    offset_ = observed;
  } else {
    // The envelope may rise with the device's drift, and falls to any frame
    // that came through faster.
    const double drift = (device_s - last_device_s_) * kMaxDriftPpm * 1e-6;
    offset_ = std::min(*offset_ + drift, observed);
  }
  last_device_s_ = device_s;
  return device_s + *offset_;
}

}  // namespace rekon::camera
