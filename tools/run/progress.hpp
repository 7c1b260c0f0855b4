#pragma once
// rekon run's progress on the terminal: frames through the mapper (the end of
// the pipeline, from the services' heartbeats on the bus), their rate, the
// realtime factor, the ETA, and every service whose state is not simply
// "running". The realtime factor is the one stats.json gives at the end: the
// recorded duration of the frames done over the wall time since the run
// started.
#include <chrono>
#include <deque>
#include <map>
#include <set>
#include <memory>
#include <string>
#include <utility>

#include "rekon/common/bus.hpp"
#include "rekon/common/config.hpp"
#include "rekon/progress/progress_line.hpp"

namespace rekon {

class RunProgress {
 public:
  // Over the last kRateWindowS of frames: the rate after a slow start-up.
  static constexpr double kRateWindowS = 3.0;

  // `total_frames` 0 and `source_fps` 0 for a live camera (no end, its own
  // rate); `first_frame_id` the id of the first frame played
  // (player.first_frame); `started` when the run started, which the realtime
  // factor counts from.
  RunProgress(const Config& config, long long total_frames, long long first_frame_id, double source_fps,
              std::chrono::steady_clock::time_point started);
  // Takes the heartbeats that arrived from `pids` (this run's children: a
  // run beside it on the same bus is not this one) and updates the line.
  void poll(const std::set<int>& pids);
  // The last line, ended: with the run's realtime factor from stats.json (0:
  // none), and without an ETA; "interrupted" when Ctrl-C stopped it.
  void finish(double realtime_factor, bool interrupted);

 private:
  std::string text() const;
  long long framesDone() const;
  // From the first frame done to the last: the run's own rate (the window's fades after the end).
  double overallRate() const;

  using Clock = std::chrono::steady_clock;
  std::unique_ptr<Bus> bus_;
  ProgressLine line_;
  long long total_, first_frame_id_;
  double source_fps_;
  struct Heard {
    int pid = 0;
    std::string state;
    long long last_frame = -1;
  };
  std::map<std::string, Heard> heard_;                                 // every service's newest heartbeat
  std::map<std::string, std::pair<std::string, long long>> services_;  // this run's: state, last frame id
  std::deque<std::pair<Clock::time_point, long long>> samples_;       // frames done over time
  std::pair<Clock::time_point, long long> first_{}, last_{};          // first frames done, last change
  Clock::time_point started_;
};

}  // namespace rekon
