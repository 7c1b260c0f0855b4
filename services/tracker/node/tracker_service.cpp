#include "tracker_service.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <thread>

#include "history.hpp"
#include "rekon/common/error.hpp"
#include "inbox.hpp"
#include "outputs.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon_msgs/done_t.hpp"
#include "tracking_worker.hpp"

namespace rekon::tracker {
namespace {

// After the end of stream, a frame that has not come within this long was
// lost on the way (message loss): the tracker finishes without it.
constexpr double kLastFrameGraceS = 3.0;
// Done_t is sent this many times, this far apart: UDP multicast may drop one,
// and the optimiser's final optimisation waits for it.
constexpr int kDoneRepeats = 3;
constexpr auto kDoneGap = std::chrono::milliseconds(50);
// How often the end-of-stream wait looks at the stop flag.
constexpr int kDrainPollMs = 100;
// How often the main thread looks for replay requests and the end.
constexpr auto kPoll = std::chrono::milliseconds(10);

// Serves replays while the bus thread tracks, until every frame up to the
// end of stream is tracked or the missing ones are given up as lost; false
// at a stop request or when the worker cannot go on.
bool trackUntilEndOfStream(ServiceContext& ctx, Inbox& inbox, const TrackingWorker& worker, History& history) {
  while (!ctx.stopRequested()) {
    if (worker.failure()) return false;
    history.serveReplays();
    inbox.releaseHeldAck();
    const int64_t end = inbox.endFrame();
    if (end != Inbox::kNoEndYet && inbox.lastTracked() >= end) return true;
    if (end != Inbox::kNoEndYet && inbox.secondsSinceLastFrame() > kLastFrameGraceS) {
      spdlog::warn("end of stream at frame {} but the last frame tracked is {}: frames {}..{} were lost; finishing",
                   end, inbox.lastTracked(), inbox.lastTracked() + 1, end);
      return true;
    }
    std::this_thread::sleep_for(kPoll);
  }
  return false;
}

// The remaining loop-closure checks (graph updates still arriving), done_t,
// then lingering: downstream services may still need us. The optimiser asks
// for a replay to fill what it lost, and a restarted one rebuilds from one; a
// restarted mapper gets its frames again, whose results go out again from
// here.
void finish(ServiceContext& ctx, Inbox& inbox, History& history, LoopClosureWorker& loops, const PeerWatch& peers) {
  spdlog::debug("end of stream: waiting for the loop-closure checks");  // the inbox logged the end once
  // Tracking is idle now: the checks left over (the stream kept both cores
  // busy, and they run below tracking's priority) get every core.
  loops.useThreads(static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
  while (!loops.waitUntilDrained(kDrainPollMs) && !ctx.stopRequested()) {
    history.serveReplays();
    inbox.releaseHeldAck();
  }
  inbox.releaseHeldAck();
  history.markDone();
  const rekon_msgs::done_t done = doneMessage("tracker", inbox.endFrame());
  for (int i = 0; i < kDoneRepeats; ++i) {
    if (i > 0) std::this_thread::sleep_for(kDoneGap);
    ctx.bus().publish(channel::kDone, done);
  }
  ctx.setState("lingering");
  while (!ctx.stopRequested() && !peers.finished({"optimiser", "mapper"})) {
    history.serveReplays();
    std::this_thread::sleep_for(kPoll);
  }
}

}  // namespace

void runTrackerService(ServiceContext& ctx) {
  const TrackerParams params = trackerParamsFromConfig(ctx.config());
  History history(ctx.bus());
  // One copy of each DVO keyframe for loop closure and relocalisation, bounded by tracker.keyframes_in_memory.
  const auto keyframes = std::make_shared<KeyframeCache>(params);
  LoopClosureWorker loops(params, [&history](const LoopConstraint& c) { history.publishLoopConstraint(c); }, true,
                          keyframes);
  const TrackerSession session = TrackerSession::fromConfig(ctx.config());
  TrackingWorker worker(params, session, history, loops, keyframes);
  PeerWatch peers(ctx.bus(), ctx.lifecycle());
  Inbox inbox(ctx, worker, history, loops, params.loop.when_behind == LoopClosureParams::WhenBehind::kHold);
  StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
  inbox.subscribe();
  ctx.setState("running");
  spdlog::info("tracking levels {}..{} ({} after a gap over {} s), keyframe criterion {}",
               params.aligner.coarsest_level, params.aligner.finest_level, params.aligner.gap_coarsest_level,
               params.aligner.gap_coarse_s, params.keyframe.criterion);

  const bool ended = trackUntilEndOfStream(ctx, inbox, worker, history);
  ctx.setState("finishing");
  if (ended) finish(ctx, inbox, history, loops, peers);
  ctx.stopThreads();  // no handler runs after this
  writeOutputs(ctx, worker.totals(), inbox.framesSentAgain(), inbox.ackHeldSeconds(), loops.stats(), keyframes->stats(),
               session.localise_only);
  if (const auto failure = worker.failure()) throw Error(*failure);  // after the outputs: what was tracked is kept
}

}  // namespace rekon::tracker
