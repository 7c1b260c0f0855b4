#pragma once
// What the mapper hears on the bus, handled on the bus thread, and the work it
// queues for the MappingWorker. Frames are copied out of the transport, joined
// with their tracked frames and acknowledged (held back while more than
// mapper.max_queued_frames are held); DVO keyframes and graph updates (a newer
// one replaces one still queued) are queued as they come; the end of the
// stream and done_t decide when the stream is over. The bus thread, the
// worker and the service's main loop share it behind one mutex.
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/rgbd_frame.hpp"
#include "rekon/common/service.hpp"
#include "rekon/mapper/mapper.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::mapper {

struct Tracked {
  int64_t keyframe_id;
  Pose pose_in_keyframe;
  bool lost;
};
struct FrameWork {
  RgbdFrame frame;
  Intrinsics k;
  Tracked tracked;
};
struct KeyframeWork {
  int64_t id;
  Pose world;
};
struct GraphWork {
  int64_t version;
  std::vector<std::pair<int64_t, Pose>> poses;
};
// The stream is over but the optimiser is not done yet: the worker would be
// idle, so it closes the last KF keyframe and writes mesh_uncorrected.ply now
// rather than after the final pass.
struct BaselineWork {};
using Work = std::variant<FrameWork, KeyframeWork, GraphWork, BaselineWork>;

// What the inbox counted, for the stats.
struct InboxCounts {
  int64_t dropped_frames = 0;
  // Of those, dropped on arrival because max_queued_frames were held
  // (mapper.when_full: drop, behind a live source).
  int64_t dropped_when_full = 0;
  // Copies of a frame already here (the player sends its newest frame again
  // while acknowledgements stall): neither stored nor counted as dropped.
  int64_t frames_received_again = 0;
  int64_t coalesced_updates = 0;
  // Frames past the resume point that came before it (Inbox::resumeFrom):
  // sent before the source heard of the restart, and sent again after.
  int64_t frames_before_resume = 0;
};

class Inbox {
 public:
  static constexpr int64_t kNoEndYet = -2;

  // `drop_when_full`: beyond max_queued_frames a frame is acknowledged and
  // dropped (a live source cannot wait), instead of its acknowledgement held.
  Inbox(ServiceContext& ctx, size_t max_queued_frames, bool drop_when_full);
  // A restarted mapper, before subscribe(): its frames resume at
  // `first_missing_frame` (Mapper::firstMissingFrame(); -1: a first start).
  // Until that frame comes, a later one is one the frame source sent before it heard of
  // the restart (its newest frame again, while acknowledgements stalled): it
  // is dropped unacknowledged, as the source sends it again in order after
  // the resume point; fused first, it made every frame between look like a
  // copy and dropped them. The wait ends `rewind_wait_s` after the first such
  // frame (the resume point's own frame was lost on the way); at 0 there is
  // none (a live source never rewinds: the frames of the outage are missed).
  void resumeFrom(int64_t first_missing_frame, double rewind_wait_s);
  // Call after the StopThreadsOnExit that guards everything the handlers use.
  void subscribe();

  // The worker's side. The next piece of work (waits for one); nullopt once
  // stopped with nothing left.
  std::optional<Work> next();
  // False when `timeout` passed with no work and no stop (the worker's idle
  // moments: the mesh publisher sends what the budget held back).
  bool waitForWork(std::chrono::milliseconds timeout);
  // After each piece of work: the worker's counters for the progress log, and
  // the acknowledgements held back that may go now.
  void finished(bool was_frame, const MapperCounters& progress);
  void failed(const std::string& error);

  // The main loop's side. True when the stream is over: the end of stream
  // came and every frame was resolved (or the tracker is done), or, with
  // wait_for_optimiser, the optimiser is done, or, for a restart with frames
  // in its store, gone (never heard within lifecycle.peer_seen_s of this
  // instance's start: it finished before this restart, and its done_t went
  // to the killed instance). Such a restart that hears neither the tracker
  // nor the optimiser within lifecycle.silence_s: the run ended while it was
  // dead, and its store's newest frame is the end. Once every frame is resolved
  // and queue_baseline, BaselineWork is queued (once).
  bool streamOver(bool wait_for_optimiser, bool queue_baseline);
  void logProgress();
  // The progress and queue as live numbers (ServiceContext::setLive).
  void publishLive();
  // Waits until the worker is idle (or failed), then lets it stop.
  void drain();

  // After the worker joined and the bus thread stopped.
  const std::string& workerError() const { return worker_error_; }
  // Frames whose tracked frame never came: counted as dropped.
  void dropUnjoinedFrames();
  int64_t endFrame() const { return end_frame_; }
  InboxCounts counts() const { return counts_; }

 private:
  void onFrame(const rekon_msgs::frame_t& msg);
  void onTrackedFrame(const rekon_msgs::tracked_frame_t& msg);
  void onKeyframe(const rekon_msgs::keyframe_t& msg);
  void onGraphUpdate(const rekon_msgs::graph_update_t& msg);
  void onEndOfStream(const rekon_msgs::end_of_stream_t& m);
  void ack(int64_t frame_id);
  // Under the lock: moves a frame whose images and pose both arrived into the queue.
  void join(int64_t id);
  // Frames held in memory: images waiting for their tracked frame, and joined
  // frames not yet fused. Counted from the containers, so no message order can
  // make it drift (a counter of its own leaked one per re-sent frame and
  // deferred every acknowledgement for good: the stall near frame 8 700).
  size_t queuedFrames() const { return images_.size() + frames_in_queue_; }
  // A frame whose images came before, or that was joined or given up on.
  bool seen(int64_t id) const { return id <= last_resolved_ || images_.count(id) > 0; }
  bool ackDeferred(int64_t id) const;
  // Under the lock: whether the image of `id` came before the resume point's
  // own frame (then dropped); ends the wait once the source has rewound.
  bool beforeResume(int64_t id);
  // `service` gone (heard, then silent), or never heard within `never_heard_s` of this instance's start.
  bool away(const std::string& service, double never_heard_s) const;
  // Under mutex_: a restart behind a source that rewinds, whose frames from
  // the resume point to the end have not all come again. The upstream's
  // done_t (heard again at once) says nothing of them; a source that sends
  // nothing for rewind_wait_s_ is not waited for.
  bool resendUnderWay() const;

  ServiceContext& ctx_;
  const size_t max_queued_;
  const bool drop_when_full_;
  std::set<int64_t> dropped_when_full_;  // images dropped on arrival whose tracked frame has not come yet
  GraphUpdateFilter filter_;  // each update carries every pose: only the newest matters
  FrameReceiver receiver_;
  PeerWatch peers_;  // whose done_t counts: the current instances' only
  const std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
  bool optimiser_gone_said_ = false;

  std::mutex mutex_;
  std::condition_variable work_ready_, idle_;
  std::deque<Work> queue_;
  std::map<int64_t, std::pair<RgbdFrame, Intrinsics>> images_;  // copied, waiting for their tracked frame
  std::map<int64_t, Tracked> tracked_;                         // waiting for their images
  std::deque<int64_t> deferred_acks_;
  size_t frames_in_queue_ = 0;  // joined frames queued or being fused
  bool busy_ = false, stop_worker_ = false;
  int64_t end_frame_ = kNoEndYet;
  int64_t last_resolved_ = -1;  // newest frame joined or given up on
  InboxCounts counts_;
  bool baseline_queued_ = false;
  int64_t resumed_from_ = -1;  // resumeFrom()'s frame; past 0: a restart with frames in its store
  // Inbox::resumeFrom: the frame a restarted mapper waits for first (-1: none
  // or it came), and the newest frame dropped while waiting, with when the
  // first was (a source that lost the resume point's frame itself rewound
  // all the same: an older frame, or rewind_wait_s_ after the first, ends the wait).
  int64_t awaiting_frame_ = -1;
  double rewind_wait_s_ = 0.0;
  int64_t newest_before_resume_ = -1;
  std::chrono::steady_clock::time_point first_before_resume_{};
  std::chrono::steady_clock::time_point last_frame_at_ = started_;  // the newest frame message, or the start
  std::string worker_error_;
  MapperCounters progress_;  // the worker's copy after each piece of work, for the progress log
};

}  // namespace rekon::mapper
