#include "optimiser_service.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <optional>
#include <thread>

#include "graph_worker.hpp"
#include "inbox.hpp"
#include "journal.hpp"
#include "outputs.hpp"
#include "recovery.hpp"
#include "rekon/common/priority.hpp"
#include "rekon/optimiser/g2o.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"

namespace rekon::optimiser {
namespace {

// How often the optimisation thread looks at the stop flag when idle.
constexpr auto kIdleWait = std::chrono::milliseconds(100);

// The journal notes an update's version before it goes out: a restart numbers its updates after it.
void publishUpdate(Bus& bus, Journal& journal, const rekon_msgs::graph_update_t& update) {
  journal.noteUpdate(update);
  bus.publish(channel::kGraphUpdates, update);
}

// A background optimisation and its graph update, published; the session's
// graph.g2o and the live numbers follow it.
void optimiseAndPublish(ServiceContext& ctx, const Inbox& inbox, GraphWorker& worker, SessionGraph& session,
                        Journal& journal) {
  publishUpdate(ctx.bus(), journal, worker.optimise(false, inbox.lastFrameId()));
  const PoseGraph& graph = worker.graph();
  session.afterOptimisation(graph, false);
  ctx.setLive("keyframes", static_cast<double>(graph.numKeyframes()));
  ctx.setLive("loop_closures", static_cast<double>(graph.numLoopEdges()));
  ctx.setLive("graph_updates", static_cast<double>(worker.optimisations()));
}

// session.continue: the previous run's graph, loaded before any replay so
// that the tracker's copies of its keyframes and constraints are duplicates,
// and published at once so that the tracker and the mapper start from its
// poses. A corrupt graph.g2o throws: the service exits with its line.
void continueSession(ServiceContext& ctx, const Inbox& inbox, GraphWorker& worker, SessionGraph& session,
                     Journal& journal) {
  const std::optional<G2oGraph> previous = session.previous();
  if (!previous || previous->vertices.empty()) return;
  worker.load(*previous);
  optimiseAndPublish(ctx, inbox, worker, session, journal);
}

// Until the upstream's done (or a stop): applies what the inbox queued and,
// when it brought new edges, optimises within the background budget and
// publishes the graph update.
// A tracker that falls silent for good before its done_t sends nothing more:
// the final step goes on with what arrived.
void optimiseWhileStreaming(ServiceContext& ctx, const PeerWatch& peers, Inbox& inbox, GraphWorker& worker,
                            SessionGraph& session, Journal& journal) {
  for (;;) {
    bool done = false;
    bool new_edges = applyArrived(inbox.waitForGraphItems(kIdleWait, &done), inbox, worker, journal);
    new_edges |= worker.applyExternal(inbox.takeExternalConstraints());
    if (done || ctx.stopRequested()) return;
    if (peers.gone(kUpstreamService)) {
      spdlog::error("rekon-tracker fell silent before its done_t; final optimisation with what arrived");
      return;
    }
    if (new_edges) optimiseAndPublish(ctx, inbox, worker, session, journal);
  }
}

// The final optimisation's update. A restart after the killed instance's
// final update sends that one's poses again (numbered anew) when they cover
// the same keyframes: optimised again, from other starting poses and with
// the outlier loop edges removed in one go, they come out otherwise, and a
// mapper in its final pass or finished keeps the first (docs/faults.md).
// The graph is optimised either way: the session's graph.g2o is its.
rekon_msgs::graph_update_t finalUpdate(GraphWorker& worker, const Inbox& inbox,
                                       const std::optional<rekon_msgs::graph_update_t>& earlier) {
  rekon_msgs::graph_update_t update = worker.optimise(true, inbox.lastFrameId());
  if (!earlier || earlier->keyframe_ids != update.keyframe_ids) return update;
  spdlog::info("the killed instance's final update (version {}, {} keyframes) covers the graph: its poses go out again",
               earlier->version, earlier->num_keyframes);
  const int64_t version = update.version;
  update = *earlier;
  update.version = version;
  return update;
}

void publishFinal(Bus& bus, const std::optional<rekon_msgs::graph_update_t>& final_update, const rekon_msgs::done_t& done,
                  const OptimiserServiceParams& params) {
  for (int i = 0; final_update && i < params.final_repeats; ++i) {
    if (i > 0) std::this_thread::sleep_for(std::chrono::milliseconds(params.final_repeat_gap_ms));
    bus.publish(channel::kGraphUpdates, *final_update);
  }
  for (int i = 0; i < params.final_repeats; ++i) {
    if (i > 0) std::this_thread::sleep_for(std::chrono::milliseconds(params.final_repeat_gap_ms));
    bus.publish(channel::kDone, done);
  }
}

// A mapper restarted after the final update still needs the final poses and
// our done_t: stay until it is done (or gone), and send them again to each
// new one.
void lingerForTheMapper(ServiceContext& ctx, const PeerWatch& peers, Inbox& inbox,
                        const rekon_msgs::graph_update_t& final_update, const rekon_msgs::done_t& done,
                        const OptimiserServiceParams& params) {
  ctx.setState("lingering");
  spdlog::info("final graph update and done_t sent; staying until rekon-mapper is finished");
  while (!ctx.stopRequested() && !peers.finished({"mapper"})) {
    if (inbox.takeMapperRestarted()) {
      spdlog::info("sending the final graph update and done again for the restarted mapper");
      publishFinal(ctx.bus(), final_update, done, params);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

}  // namespace

void runOptimiserService(ServiceContext& ctx) {
  const OptimiserServiceParams params = optimiserParamsFromConfig(ctx.config());
  // This thread, which optimises (the bus thread, started before, keeps its priority).
  applyNice(params.nice, "optimiser.nice");
  Inbox inbox(ctx, params.information_scale);
  PeerWatch peers(ctx.bus(), ctx.lifecycle());
  StopThreadsOnExit stop_threads(ctx);  // before `inbox` dies: the bus handlers write into it
  inbox.subscribe(peers);
  ctx.setState("running");
  spdlog::info("pose graph: information x {}, {} loss (scale {}) on loop edges, outlier chi2 > {}, {} iterations "
               "per background optimisation",
               params.information_scale, toString(params.graph.loop_loss), params.graph.loop_loss_scale,
               params.graph.loop_outlier_chi2, params.graph.max_iterations);

  GraphWorker worker(params.graph);
  if (!ctx.outDir().empty())
    worker.logTimingTo(ctx.outDir() + "/optimiser_timing.csv", ctx.config().getBool("optimiser.restarted"));
  SessionGraph session(ctx.config());
  Journal journal(ctx.outDir(), ctx.config().getBool("optimiser.restarted"));
  continueSession(ctx, inbox, worker, session, journal);
  if (!journal.enabled()) inbox.holdFrames();  // else the final step reads them back from the journal
  const ReplayCursor from = rebuildFromJournal(journal.contents(), inbox, worker);
  const std::optional<rekon_msgs::graph_update_t> earlier_final = journal.contents().final_update;
  journal.forgetContents();
  ReplayClient replays(ctx, peers, inbox);
  if (!recoverAtStart(ctx, peers, replays, inbox, worker, from)) {
    // Nothing to add, but a mapper may wait for the optimiser's current instance.
    publishFinal(ctx.bus(), std::nullopt, doneMessage(ctx.name(), -1), params);
    return;
  }
  optimiseWhileStreaming(ctx, peers, inbox, worker, session, journal);

  ctx.setState("finishing");
  fillWhatWasLost(ctx, replays, inbox, worker, journal);
  applyArrived(inbox.takeGraphItems(), inbox, worker, journal);
  worker.applyExternal(inbox.takeExternalConstraints());
  const rekon_msgs::graph_update_t final_update = finalUpdate(worker, inbox, earlier_final);
  journal.noteUpdate(final_update);  // publishFinal sends it (again for a restarted mapper)
  session.afterOptimisation(worker.graph(), true);
  const Inbox::Final final_state = inbox.takeFinal();
  worker.countRejected(final_state.rejected);
  const size_t trajectory_frames =
      writeTrajectory(ctx, final_update, journal.enabled() ? journal.trackedFrames() : final_state.frames);

  const rekon_msgs::done_t done = doneMessage(ctx.name(), final_state.last_frame_id);
  publishFinal(ctx.bus(), final_update, done, params);
  lingerForTheMapper(ctx, peers, inbox, final_update, done, params);
  setStats(ctx, worker, trajectory_frames);
}

}  // namespace rekon::optimiser
