#include "tracker_service.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <optional>
#include <thread>

#include "history.hpp"
#include "rekon/common/csv_log.hpp"
#include "rekon/common/error.hpp"
#include "inbox.hpp"
#include "outputs.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon_msgs/done_t.hpp"
#include "tracker_state.hpp"
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

// A restarted tracker's resume point, announced at the start and once a
// second after (as the mapper's): a frame source that missed one finds the next.
class ResumeAnnouncer {
 public:
  ResumeAnnouncer(Bus& bus, std::optional<rekon_msgs::resume_point_t> point) : bus_(bus), point_(std::move(point)) {
    tick(true);
  }
  void tick(bool now = false) {
    if (!point_ || (!now && std::chrono::steady_clock::now() - last_ < std::chrono::seconds(1))) return;
    last_ = std::chrono::steady_clock::now();
    bus_.publish(channel::kResumePoint, *point_);
  }

 private:
  Bus& bus_;
  std::optional<rekon_msgs::resume_point_t> point_;
  std::chrono::steady_clock::time_point last_;
};

// Serves replays while the bus thread tracks, until every frame up to the
// end of stream is tracked or the missing ones are given up as lost; false
// at a stop request or when the worker cannot go on.
bool trackUntilEndOfStream(ServiceContext& ctx, Inbox& inbox, const TrackingWorker& worker, History& history,
                           ResumeAnnouncer& resume) {
  while (!ctx.stopRequested()) {
    if (worker.failure()) return false;
    resume.tick();
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
void finish(ServiceContext& ctx, Inbox& inbox, History& history, LoopClosureWorker& loops, const PeerWatch& peers,
            ResumeAnnouncer& resume) {
  spdlog::debug("end of stream: waiting for the loop-closure checks");  // the inbox logged the end once
  // Tracking is idle now: the checks left over (the stream kept both cores
  // busy, and they run below tracking's priority) get every core.
  loops.useThreads(static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
  while (!loops.waitUntilDrained(kDrainPollMs) && !ctx.stopRequested()) {
    resume.tick();
    history.serveReplays();
    inbox.releaseHeldAck();
  }
  inbox.releaseHeldAck();
  const rekon_msgs::done_t done = doneMessage("tracker", inbox.endFrame());
  history.markDone(done);
  for (int i = 0; i < kDoneRepeats; ++i) {
    if (i > 0) std::this_thread::sleep_for(kDoneGap);
    ctx.bus().publish(channel::kDone, done);
  }
  ctx.setState("lingering");
  while (!ctx.stopRequested() && !peers.finished({"optimiser", "mapper"})) {
    resume.tick();
    history.serveReplays();
    std::this_thread::sleep_for(kPoll);
  }
}

}  // namespace

void runTrackerService(ServiceContext& ctx) {
  const auto started = std::chrono::steady_clock::now();
  const TrackerParams params = trackerParamsFromConfig(ctx.config());
  const bool restarted = ctx.config().getBool("tracker.restarted");
  TrackerState state(ctx.outDir(), restarted);
  History history(ctx.bus(), state.journal());
  // One copy of each DVO keyframe for loop closure and relocalisation, bounded by tracker.keyframes_in_memory.
  const auto keyframes = std::make_shared<KeyframeCache>(params);
  // <out>/tracker_loop_checks.csv, a row per keyframe's check as it ends (rekon bench longrun's loop-check
  // time per keyframe); declared before the worker, whose thread writes it.
  std::optional<CsvLog> checks;
  if (!ctx.outDir().empty())
    checks.emplace(ctx.outDir() + "/tracker_loop_checks.csv", "keyframe_id,frame_id,candidates,accepted,ms", restarted);
  // Started once a restart has indexed the earlier keyframes in it.
  LoopClosureWorker loops(params, [&history](const LoopConstraint& c) { history.publishLoopConstraint(c); }, false,
                          keyframes);
  const TrackerSession session = TrackerSession::fromConfig(ctx.config());
  TrackingWorker worker(params, session, history, loops, keyframes, &state);
  PeerWatch peers(ctx.bus(), ctx.lifecycle());
  Inbox inbox(ctx, worker, history, loops, params.loop.when_behind == LoopClosureParams::WhenBehind::kHold);
  std::optional<rekon_msgs::resume_point_t> resume_point;
  loops.onSettled([&history](int64_t id) { history.noteLoopChecked(id); });
  loops.onChecked([&checks](int64_t keyframe_id, int64_t frame_id, const LoopClosureStats& check, double ms) {
    if (checks) checks->row(keyframe_id, frame_id, check.candidates, check.accepted, ms);
  });
  if (restarted)
    resume_point = restoreAfterRestart(ctx, state, history, *keyframes, worker, loops, inbox, params.aligner);
  loops.start();
  StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
  inbox.subscribe();
  ResumeAnnouncer resume(ctx.bus(), resume_point);
  if (restarted)
    spdlog::info("restart: ready for frames {:.0f} ms after the start",
                 std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - started).count());
  ctx.setState("running");
  spdlog::info("tracking levels {}..{} ({} after a gap over {} s), keyframe criterion {}",
               params.aligner.coarsest_level, params.aligner.finest_level, params.aligner.gap_coarsest_level,
               params.aligner.gap_coarse_s, params.keyframe.criterion);

  const bool ended = trackUntilEndOfStream(ctx, inbox, worker, history, resume);
  ctx.setState("finishing");
  if (ended) finish(ctx, inbox, history, loops, peers, resume);
  ctx.stopThreads();  // no handler runs after this
  ctx.stats()
      .set("keyframes_archived", state.archived())
      .set("archive_ms", state.archiveMs())
      .set("frames_before_resume", inbox.framesBeforeResume());
  if (const RecordJournal* journal = state.journal()) {
    const RecordJournal::Appended& a = journal->appended();
    ctx.stats()
        .set("journal_records", a.records)
        .set("journal_bytes", a.bytes)
        .set("journal_append_ms", 1e3 * a.seconds);
  }
  if (restarted)
    ctx.stats().set("restart_first_pose", worker.resumedBy()).set("frames_restored", worker.totals().restored_frames);
  writeOutputs(ctx, worker.totals(), inbox.framesSentAgain(), inbox.ackHeldSeconds(), loops.stats(), keyframes->stats(),
               session.localise_only);
  if (const auto failure = worker.failure()) {  // after the outputs: what was tracked is kept
    state.markFailed(*failure);
    throw Error(*failure);
  }
  if (ended && !ctx.stopRequested()) state.removeArchive();
}

}  // namespace rekon::tracker
