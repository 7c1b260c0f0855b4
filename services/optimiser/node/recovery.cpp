#include "recovery.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <limits>
#include <thread>

#include "rekon_msgs/replay_request_t.hpp"

namespace rekon::optimiser {
namespace {

using Clock = std::chrono::steady_clock;

// Messages per batch: a few milliseconds of the tracker's main thread, and a
// burst any socket buffer takes.
constexpr int32_t kBatchItems = 200;
// A cursor past anything the tracker will ever have: the answer carries only its totals.
constexpr int64_t kNoItems = std::numeric_limits<int64_t>::max();
// A restarted optimiser numbers its graph updates after the newest version its
// journal noted; when the tracker saw a newer one (no journal: no --out, or
// its writes failed), from that plus this, so that consumers (which ignore
// versions they have seen) take them even when the tracker missed the last
// few updates.
constexpr int64_t kRestartVersionGap = 1000;

Clock::time_point secondsFromNow(double s) {
  return Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
}

struct Have {
  int64_t keyframes, constraints, frames;
};

Have have(const Inbox& inbox, const GraphWorker& worker) {
  return {static_cast<int64_t>(worker.keyframesSeen()), static_cast<int64_t>(worker.constraintsSeen()),
          static_cast<int64_t>(inbox.trackedFrameCount())};
}

}  // namespace

std::optional<rekon_msgs::replay_end_t> ReplayClient::batch(const ReplayCursor& from) {
  rekon_msgs::replay_request_t req{};
  req.service = ctx_.name();
  req.pid = getpid();
  req.next_keyframe = from.keyframe;
  req.next_constraint = from.constraint;
  req.next_frame_id = from.frame_id;
  req.max_items = kBatchItems;
  while (!ctx_.stopRequested() && peers_.alive(kUpstreamService)) {  // nobody else answers
    req.request_id = ++request_id_;  // a late answer to an earlier ask is not taken for this one
    ctx_.bus().publish(channel::kReplayRequest, req);
    if (auto end = inbox_.waitForReplayEnd(req.request_id, secondsFromNow(ctx_.lifecycle().replay_answer_s))) return end;
    spdlog::warn("no answer from rekon-tracker to a replay batch within {:.1f} s (lifecycle.replay_answer_s); asking again",
                 ctx_.lifecycle().replay_answer_s);
  }
  return std::nullopt;
}

std::optional<rekon_msgs::replay_end_t> ReplayClient::totals() {
  ReplayCursor nothing{kNoItems, kNoItems, kNoItems};
  return batch(nothing);
}

std::optional<rekon_msgs::replay_end_t> ReplayClient::replay(ReplayCursor from) {
  for (;;) {
    auto end = batch(from);
    if (!end || end->complete) return end;
    from = {end->next_keyframe, end->next_constraint, end->next_frame_id};
  }
}

ReplayCursor rebuildFromJournal(const JournalContents& journal, Inbox& inbox, GraphWorker& worker) {
  const size_t keyframes_before = worker.keyframesSeen(), constraints_before = worker.constraintsSeen();
  worker.apply(journal.items);
  inbox.restoreFrames(journal.frames);
  if (journal.newest_version > worker.version()) {
    worker.continueVersionsAfter(journal.newest_version);
    spdlog::info("graph updates continue after version {}, the newest an earlier instance published",
                 journal.newest_version);
  }
  // The journal's newest frame, not the inbox's: live frames heard since this
  // instance subscribed may have left a gap after the journal.
  int64_t newest = -1;
  for (const TrackedFrame& f : journal.frames) newest = std::max(newest, f.frame_id);
  const ReplayCursor from{static_cast<int64_t>(worker.keyframesSeen() - keyframes_before),
                          static_cast<int64_t>(worker.constraintsSeen() - constraints_before), newest + 1};
  if (journal.records_read > 0)
    spdlog::info("rebuilt from {}: {} keyframes, {} constraints, {} tracked frames; the tracker's replay starts after them",
                 kJournalFile, from.keyframe, from.constraint, journal.frames.size());
  return from;
}

bool recoverAtStart(ServiceContext& ctx, const PeerWatch& peers, ReplayClient& replays, Inbox& inbox,
                    GraphWorker& worker, const ReplayCursor& from) {
  const bool restarted = ctx.config().getBool("optimiser.restarted");
  const auto wait_until = secondsFromNow(ctx.lifecycle().peer_seen_s);
  while (!peers.peer(kUpstreamService) && Clock::now() < wait_until && !ctx.stopRequested())
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const auto tracker = peers.peer(kUpstreamService);
  if (!tracker && restarted) {
    spdlog::warn("restarted, but no rekon-tracker heartbeat within {:.1f} s (it has finished and exited): nothing to "
                 "rebuild from; the outputs already written stay as they are",
                 ctx.lifecycle().peer_seen_s);
    return false;
  }
  if (!tracker || tracker->instances == 0) return true;
  const auto end = replays.replay(from);
  if (!end) return true;
  // A version the tracker saw from us (the previous run's graph, published at
  // once with session.continue) does not make this optimiser a restart.
  if (end->graph_version > worker.version()) {
    worker.continueVersionsAfter(end->graph_version + kRestartVersionGap);
    spdlog::warn("the tracker has seen graph version {}: this optimiser is a restart; rebuilt from its journal and "
                 "the tracker's replay from keyframe {}, constraint {}, frame {} (the tracker has {} keyframes, {} "
                 "constraints, {} tracked frames)",
                 end->graph_version, from.keyframe, from.constraint, from.frame_id, end->keyframes, end->constraints,
                 end->tracked_frames);
  }
  // Its done_t may have gone out before we subscribed: the replay says so.
  if (end->done) {
    spdlog::info("the tracker finished before this optimiser started: final optimisation after the replay");
    inbox.setUpstreamDone();
  }
  return true;
}

void fillWhatWasLost(ServiceContext& ctx, ReplayClient& replays, Inbox& inbox, GraphWorker& worker, Journal& journal) {
  auto totals = replays.totals();
  while (totals && !ctx.stopRequested()) {
    const Have now = have(inbox, worker);
    const Have missing{totals->keyframes - now.keyframes, totals->constraints - now.constraints,
                       totals->tracked_frames - now.frames};
    if (missing.keyframes <= 0 && missing.constraints <= 0 && missing.frames <= 0) break;
    spdlog::warn("missing after the stream: {} keyframes, {} constraints, {} tracked frames of the tracker's; "
                 "asking for them again",
                 missing.keyframes, missing.constraints, missing.frames);
    // A lost message can be anywhere: the kinds with something missing are
    // replayed from their start, the others not at all.
    const ReplayCursor from{missing.keyframes > 0 ? 0 : totals->keyframes,
                            missing.constraints > 0 ? 0 : totals->constraints,
                            missing.frames > 0 ? 0 : totals->last_frame_id + 1};
    totals = replays.replay(from);
    applyArrived(inbox.takeGraphItems(), inbox, worker, journal);
    const Have after = have(inbox, worker);
    if (after.keyframes == now.keyframes && after.constraints == now.constraints && after.frames == now.frames) {
      spdlog::error("a whole replay brought nothing new; optimising what arrived");
      break;
    }
  }
  if (worker.constraintsWaiting() > 0)
    spdlog::error("{} constraints name a keyframe that never arrived; left out", worker.constraintsWaiting());
}

}  // namespace rekon::optimiser
