#pragma once
// What the tracker hears on the bus, handled on the bus thread: frames
// (tracked at once by the TrackingWorker, or answered from the History when
// sent again), the end of stream, graph updates for the loop-closure checks,
// replay requests and restarted mappers.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>

#include "history.hpp"
#include "rekon/common/service.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "tracking_worker.hpp"

namespace rekon::tracker {

class Inbox {
 public:
  static constexpr int64_t kNoEndYet = -2;

  // `hold_when_behind` (tracker.loop_when_behind: hold): while the loop
  // checks are behind, frame acknowledgements are held back, so that a
  // source that waits for them (a recording at rate max) waits for the checks.
  Inbox(ServiceContext& ctx, TrackingWorker& worker, History& history, LoopClosureWorker& loops, bool hold_when_behind);
  // Call after the StopThreadsOnExit that guards everything the handlers use.
  void subscribe();
  // A restarted tracker (before subscribe()): frames before `first_missing`
  // were tracked by the killed instance (their stored results answer them);
  // a later frame that comes first (the source's newest, sent again before it
  // heard of the restart) is dropped unacknowledged and comes again in its
  // turn, unless the source has not rewound within `rewind_wait_s` (a live
  // source goes on from its next frame). -1: every frame is new.
  void resumeFrom(int64_t first_missing, double rewind_wait_s);
  // A restarted tracker whose killed instance had finished: the stream ended at `last_frame_id`.
  void endAt(int64_t last_frame_id) { end_frame_.store(last_frame_id); }
  int64_t framesBeforeResume() const { return before_resume_.load(); }

  // The last frame id of the end of stream; kNoEndYet before it came.
  int64_t endFrame() const { return end_frame_.load(); }
  // The newest frame tracked; -1 before the first.
  int64_t lastTracked() const { return last_handled_.load(); }
  double secondsSinceLastFrame() const;
  int64_t framesSentAgain() const { return duplicates_.load(); }
  // Sends the acknowledgement held back once the loop checks are no longer
  // behind; the main thread calls it every few milliseconds.
  void releaseHeldAck();
  // How long acknowledgements were held back, in all.
  double ackHeldSeconds() const;

 private:
  using Clock = std::chrono::steady_clock;
  void onFrame(const rekon_msgs::frame_t& msg);
  void publishLive();  // the tracking counts (ServiceContext::setLive)
  void onGraphUpdate(const rekon_msgs::graph_update_t& m);
  void onEndOfStream(const rekon_msgs::end_of_stream_t& m);
  // Acknowledges every frame up to `frame_id` now, or later (releaseHeldAck).
  void acknowledge(int64_t frame_id);
  // Under ack_mutex_: sends the held acknowledgement (and `frame_id`'s when newer).
  void sendAckLocked(int64_t frame_id);

  ServiceContext& ctx_;
  TrackingWorker& worker_;
  History& history_;
  LoopClosureWorker& loops_;
  std::atomic<int64_t> last_handled_{-1};
  std::atomic<int64_t> end_frame_{kNoEndYet};
  std::atomic<int64_t> duplicates_{0};
  std::atomic<Clock::rep> last_frame_at_{Clock::now().time_since_epoch().count()};
  const bool hold_when_behind_;
  mutable std::mutex ack_mutex_;
  int64_t held_ack_ = -1;  // the newest frame whose acknowledgement is held back; -1: none
  Clock::time_point held_since_;
  double held_s_ = 0.0;
  int64_t resume_from_ = -1;  // resumeFrom(): waiting for this frame; -1: not waiting
  Clock::time_point resume_since_;
  double rewind_wait_s_ = 0.0;
  std::atomic<int64_t> before_resume_{0};
};

}  // namespace rekon::tracker
