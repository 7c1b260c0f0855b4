#pragma once
// What the optimiser hears on the bus. The bus thread only validates and
// queues, so it never waits for the solver; the optimisation thread takes the
// queue. Keyframes, constraints and tracked frames come live and again in the
// tracker's replays; replay answers, the tracker's done_t and restarted
// mappers are noted here too. Every method is safe from any thread.
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <variant>
#include <vector>

#include "rekon/common/error.hpp"
#include "rekon/common/service.hpp"
#include "frame_ids.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon_msgs/replay_end_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::optimiser {

// The upstream whose done_t starts the final optimisation.
inline constexpr const char* kUpstreamService = "tracker";

using GraphItem = std::variant<KeyframeIn, Constraint>;

class Inbox {
 public:
  using Clock = std::chrono::steady_clock;

  Inbox(ServiceContext& ctx, double information_scale);
  // Call after the StopThreadsOnExit that guards the inbox.
  void subscribe(PeerWatch& peers);

  // Waits at most `timeout` for graph items or the upstream's done; takes the
  // items queued so far, in arrival order. `upstream_done` true means every
  // item the upstream sent before its done_t is among them: the bus thread
  // queues messages in arrival order.
  std::vector<GraphItem> waitForGraphItems(std::chrono::milliseconds timeout, bool* upstream_done);
  std::vector<GraphItem> takeGraphItems();
  // External constraints (EXTERNAL_CONSTRAINTS) queued so far; they wake
  // waitForGraphItems too.
  std::vector<ExternalConstraint> takeExternalConstraints();
  // The replay_end_t answering `request_id`, or nullopt at the deadline.
  std::optional<rekon_msgs::replay_end_t> waitForReplayEnd(int64_t request_id, Clock::time_point deadline);
  // The upstream finished before we could hear its done_t (a replay says so).
  void setUpstreamDone();

  // Tracked frames first heard since the last call (live or replayed), in
  // arrival order: the journal's.
  std::vector<TrackedFrame> takeNewFrames();
  // An earlier instance's frames (its journal), as if they had arrived, but
  // not new: they are in the journal already.
  void restoreFrames(const std::vector<TrackedFrame>& frames);
  // Without a journal (no out dir) the inbox keeps every frame for Final;
  // with one it keeps only their ids, and the final step reads them back.
  void holdFrames() { hold_frames_ = true; }

  size_t trackedFrameCount() const;
  int64_t lastFrameId() const;
  // True once per mapper restart noted since the last call.
  bool takeMapperRestarted();

  struct Final {
    std::vector<TrackedFrame> frames;  // holdFrames(): every tracked frame, live and replayed, once each, by id
    int64_t last_frame_id = -1;
    int64_t rejected = 0;  // messages that did not validate
  };
  // What the final step needs; forgets the mapper restarts noted so far (the
  // final update goes out now anyway).
  Final takeFinal();

 private:
  void reject(const Error& e);
  void queue(GraphItem item);
  void onTrackedFrame(const rekon_msgs::tracked_frame_t& m);

  ServiceContext& ctx_;
  const double information_scale_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::vector<GraphItem> graph_items_;          // in arrival order
  std::vector<ExternalConstraint> externals_;   // in arrival order
  FrameIds frame_ids_;                          // live and replayed, once each
  std::vector<TrackedFrame> new_frames_;        // not yet taken by takeNewFrames
  bool hold_frames_ = false;
  std::map<int64_t, TrackedFrame> held_frames_;  // holdFrames()
  bool upstream_done_ = false;
  int64_t last_frame_id_ = -1;
  int64_t rejected_ = 0;
  std::optional<rekon_msgs::replay_end_t> replay_end_;  // the newest answer to our request
  bool mapper_restarted_ = false;
};

}  // namespace rekon::optimiser
