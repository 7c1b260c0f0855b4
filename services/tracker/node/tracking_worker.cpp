#include "tracking_worker.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <optional>

#include "rekon/common/camera.hpp"
#include "rekon/common/cpu_time.hpp"
#include "rekon/common/rgbd_frame.hpp"

namespace rekon::tracker {

TrackingWorker::TrackingWorker(const TrackerParams& params, History& history, LoopClosureWorker& loops)
    : history_(history), loops_(loops), tracker_(params) {}

bool TrackingWorker::track(const rekon_msgs::frame_t& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  Intrinsics k;
  std::optional<RgbdFrame> frame = receiver_.receive(msg, &k);
  if (!frame) {
    ++totals_.undecodable;
    return false;
  }
  const double t0 = threadCpuMs();
  const auto w0 = std::chrono::steady_clock::now();
  const TrackResult r = tracker_.track(*frame, k);
  totals_.frame_ms.emplace_back(
      r.frame_id, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - w0).count());
  totals_.track_cpu_s += 1e-3 * (threadCpuMs() - t0);
  ++totals_.frames;
  totals_.lost += r.state == TrackingState::Lost;
  totals_.keyframes += r.new_keyframe;
  totals_.constraints += r.odometry.has_value();
  totals_.odometry.push_back({r.timestamp, r.pose_world});
  totals_.lost_intervals.add(r);
  if (r.state == TrackingState::Lost) spdlog::warn("frame {}: lost ({})", r.frame_id, toString(r.lost_reason));
  history_.publishResult(r);
  if (r.new_keyframe) loops_.submit(tracker_.currentKeyframe(), r.odometry);
  return true;
}

TrackingCounts TrackingWorker::counts() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return totals_;
}

TrackingTotals TrackingWorker::totals() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return totals_;
}

}  // namespace rekon::tracker
