#pragma once
// Replays from the tracker (messages/recovery.lcm): at start-up, where a
// restarted optimiser rebuilds its graph (a first one gets an empty answer),
// and at the tracker's done when something was lost on the way.
#include <cstdint>
#include <optional>

#include "graph_worker.hpp"
#include "inbox.hpp"
#include "rekon/common/service.hpp"
#include "rekon_msgs/replay_end_t.hpp"

namespace rekon::optimiser {

class ReplayClient {
 public:
  ReplayClient(ServiceContext& ctx, Inbox& inbox) : ctx_(ctx), inbox_(inbox) {}
  // Asks the tracker for a replay and waits for its answer, asking again when
  // none comes; nullopt when none came (no tracker, or every try lost).
  std::optional<rekon_msgs::replay_end_t> request();

 private:
  ServiceContext& ctx_;
  Inbox& inbox_;
  int64_t request_id_ = 0;
};

// A restarted optimiser finds the tracker's history in a replay: its updates
// continue past the newest graph version the tracker saw, and when the
// tracker has already finished, the final optimisation follows the replay. A
// tracker still starting has no history; without a tracker (another
// frontend, a test) nobody would answer, so it is asked only when its
// heartbeat comes within a moment.
void recoverAtStart(ServiceContext& ctx, const PeerWatch& peers, ReplayClient& replays, Inbox& inbox,
                    GraphWorker& worker);

// After the stream: the tracker's totals tell whether anything is missing,
// and a replay supplies it (each item is taken once).
void fillWhatWasLost(ServiceContext& ctx, const PeerWatch& peers, ReplayClient& replays, Inbox& inbox,
                     GraphWorker& worker);

}  // namespace rekon::optimiser
