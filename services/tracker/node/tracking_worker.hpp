#pragma once
// Tracks the frames the bus thread hands it, one at a time and in order,
// publishes each result through the History, and hands each new DVO keyframe
// to the loop-closure worker after its result is out (so that a loop
// constraint never reaches the bus before its keyframe).
#include <cstdint>
#include <mutex>
#include <utility>
#include <vector>

#include "history.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/lost_intervals.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/tracker.hpp"
#include "rekon_msgs/frame_t.hpp"

namespace rekon::tracker {

struct TrackingCounts {
  int64_t frames = 0, lost = 0, keyframes = 0, constraints = 0, undecodable = 0;
};

struct TrackingTotals : TrackingCounts {
  double track_cpu_s = 0.0;
  std::vector<std::pair<int64_t, double>> frame_ms;  // wall time of track() (pyramid included) per frame
  Trajectory odometry;                               // world poses by odometry alone
  LostIntervals lost_intervals;
};

class TrackingWorker {
 public:
  TrackingWorker(const TrackerParams& params, History& history, LoopClosureWorker& loops);

  // Decodes and tracks one frame; false when it does not decode (the
  // receiver logged why).
  bool track(const rekon_msgs::frame_t& msg);
  TrackingTotals totals() const;
  TrackingCounts counts() const;  // cheap: no per-frame tables

 private:
  History& history_;
  LoopClosureWorker& loops_;
  mutable std::mutex mutex_;
  Tracker tracker_;
  FrameReceiver receiver_;
  TrackingTotals totals_;
};

}  // namespace rekon::tracker
