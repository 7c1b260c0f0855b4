#pragma once
// Replays from the tracker (messages/recovery.lcm): at start-up, where a
// restarted optimiser rebuilds its graph (a first one gets an empty answer),
// and at the tracker's done when something was lost on the way. A replay is
// a series of batches, each asked for from the cursor the last one ended at,
// so the tracker never sends faster than this optimiser takes them.
#include <cstdint>
#include <optional>

#include "graph_worker.hpp"
#include "inbox.hpp"
#include "journal.hpp"
#include "rekon/common/service.hpp"
#include "rekon_msgs/replay_end_t.hpp"

namespace rekon::optimiser {

// Where a replay starts (or goes on): the tracker's publication order.
struct ReplayCursor {
  int64_t keyframe = 0, constraint = 0, frame_id = 0;
};

class ReplayClient {
 public:
  ReplayClient(ServiceContext& ctx, const PeerWatch& peers, Inbox& inbox) : ctx_(ctx), peers_(peers), inbox_(inbox) {}
  // Asks the tracker for everything from `from` on, batch after batch, until
  // a batch reaches the end of what it has. A batch unanswered for
  // lifecycle.replay_answer_s is asked for again; nullopt once the tracker is
  // gone, when none was ever heard (another frontend, a test), or at a stop.
  // The answer's counts are the tracker's totals.
  std::optional<rekon_msgs::replay_end_t> replay(ReplayCursor from);
  // The tracker's totals alone (an empty batch); nullopt once it is gone.
  std::optional<rekon_msgs::replay_end_t> totals();

 private:
  std::optional<rekon_msgs::replay_end_t> batch(const ReplayCursor& from);
  ServiceContext& ctx_;
  const PeerWatch& peers_;
  Inbox& inbox_;
  int64_t request_id_ = 0;
};

// An earlier instance's journal, applied as if it had arrived; returns where
// the tracker's replay goes on: after the keyframes, constraints (distinct
// ones, as the worker counts them) and the newest frame the journal holds.
// What the journal missed in between (a message lost on its way) is found by
// fillWhatWasLost, which compares with the tracker's totals.
ReplayCursor rebuildFromJournal(const JournalContents& journal, Inbox& inbox, GraphWorker& worker);

// A restarted optimiser finds the rest of the tracker's history (from `from`) in a replay: its updates
// continue past the newest graph version the tracker saw, and when the
// tracker has already finished, the final optimisation follows the replay. A
// tracker still starting has no history; without a tracker (another
// frontend, a test) nobody would answer, so it is asked only when its
// heartbeat comes within lifecycle.peer_seen_s. False when this optimiser
// was restarted (optimiser.restarted) and no tracker is there to rebuild
// from: it has nothing to add.
bool recoverAtStart(ServiceContext& ctx, const PeerWatch& peers, ReplayClient& replays, Inbox& inbox,
                    GraphWorker& worker, const ReplayCursor& from);

// After the stream: the tracker's totals tell whether anything is missing,
// and a replay supplies it (each item is taken once), until nothing is
// missing, the tracker is gone, or a replay brought nothing new.
void fillWhatWasLost(ServiceContext& ctx, ReplayClient& replays, Inbox& inbox, GraphWorker& worker, Journal& journal);

}  // namespace rekon::optimiser
