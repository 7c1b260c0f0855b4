#include "optimiser_service.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <thread>
#include <tuple>
#include <variant>
#include <vector>

#include "rekon/common/error.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/replay_end_t.hpp"
#include "rekon_msgs/replay_request_t.hpp"

namespace rekon::optimiser {
namespace {

using Clock = std::chrono::steady_clock;

// The upstream whose done_t starts the final optimisation.
constexpr const char* kUpstreamService = "tracker";
// How often the optimisation thread looks at the stop flag when idle.
constexpr auto kIdleWait = std::chrono::milliseconds(100);
// Replays from the tracker (messages/recovery.lcm): at start-up (a restarted
// optimiser rebuilds its graph; a first one gets an empty answer) and at the
// tracker's done when something was lost on the way. A request unanswered
// this long is sent again, at most kReplayTries times.
constexpr double kReplayAnswerS = 2.0;
constexpr int kReplayTries = 4;
// How long a starting optimiser listens for the tracker's heartbeat.
constexpr double kTrackerSeenS = 1.5;
// A restarted optimiser numbers its graph updates from the newest version the
// tracker saw plus this, so that consumers (which ignore versions they have
// seen) take them even when the tracker missed the last few updates.
constexpr int64_t kRestartVersionGap = 1000;

// What the bus thread hands to the optimisation thread: the handlers only
// validate and queue, so the bus thread never waits for Ceres.
struct Inbox {
  std::mutex mutex;
  std::condition_variable wake;
  std::vector<std::variant<KeyframeIn, Constraint>> graph_items;  // in arrival order
  std::map<int64_t, TrackedFrame> frames;                         // live and replayed, once each
  bool upstream_done = false;
  int64_t last_frame_id = -1;
  int64_t rejected = 0;
  std::optional<rekon_msgs::replay_end_t> replay_end;  // the newest answer to our request
  bool mapper_restarted = false;
};

// Keyframes and constraints arrive live and again in replays: each is added
// to the graph once. A constraint whose keyframes have not arrived (lost on
// the way) waits for them.
struct GraphFeed {
  std::set<int64_t> keyframes;
  std::set<std::tuple<int, int64_t, int64_t>> constraints;  // kind, from, to
  std::vector<Constraint> waiting;
  int64_t duplicates = 0;
};

struct Totals {
  int64_t optimisations = 0;
  double optimise_ms = 0.0;
  int64_t rejected = 0;
  std::vector<std::tuple<int64_t, double, size_t, int64_t>> timing;  // last frame id, ms, keyframes, version
};

void reject(Inbox& inbox, const Error& e) {
  spdlog::error("{}", e.what());
  std::lock_guard<std::mutex> lock(inbox.mutex);
  ++inbox.rejected;
}

void subscribe(ServiceContext& ctx, Inbox& inbox, double information_scale) {
  Bus& bus = ctx.bus();
  auto onKeyframe = [&inbox](const rekon_msgs::keyframe_t& m) {
    try {
      KeyframeIn kf = keyframeFromMsg(m);
      std::lock_guard<std::mutex> lock(inbox.mutex);
      inbox.graph_items.emplace_back(kf);
    } catch (const Error& e) {
      reject(inbox, e);
      return;
    }
    inbox.wake.notify_one();
  };
  auto onConstraint = [&inbox, information_scale](const rekon_msgs::constraint_t& m) {
    try {
      Constraint c = constraintFromMsg(m, information_scale);
      std::lock_guard<std::mutex> lock(inbox.mutex);
      inbox.graph_items.emplace_back(c);
    } catch (const Error& e) {
      reject(inbox, e);
      return;
    }
    inbox.wake.notify_one();
  };
  auto onTracked = [&inbox](const rekon_msgs::tracked_frame_t& m) {
    try {
      TrackedFrame f = trackedFrameFromMsg(m);
      std::lock_guard<std::mutex> lock(inbox.mutex);
      inbox.frames.emplace(f.frame_id, f);
      inbox.last_frame_id = std::max(inbox.last_frame_id, f.frame_id);
    } catch (const Error& e) {
      reject(inbox, e);
    }
  };
  bus.subscribe<rekon_msgs::keyframe_t>(channel::kKeyframes, onKeyframe);
  bus.subscribe<rekon_msgs::keyframe_t>(channel::kKeyframesResent, onKeyframe);
  bus.subscribe<rekon_msgs::constraint_t>(channel::kConstraints, onConstraint);
  bus.subscribe<rekon_msgs::constraint_t>(channel::kConstraintsResent, onConstraint);
  bus.subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFrames, [onTracked, &ctx](const rekon_msgs::tracked_frame_t& m) {
    onTracked(m);
    ctx.setLastFrame(m.frame_id);
  });
  bus.subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFramesResent, onTracked);
  bus.subscribe<rekon_msgs::replay_end_t>(channel::kReplayEnd, [&inbox, &ctx](const rekon_msgs::replay_end_t& m) {
    if (m.service != ctx.name()) return;
    {
      std::lock_guard<std::mutex> lock(inbox.mutex);
      inbox.replay_end = m;
    }
    inbox.wake.notify_one();
  });
  bus.subscribe<rekon_msgs::done_t>(channel::kDone, [&inbox](const rekon_msgs::done_t& m) {
    if (m.service != kUpstreamService) return;
    {
      std::lock_guard<std::mutex> lock(inbox.mutex);
      if (inbox.upstream_done) return;  // done_t is sent several times
      inbox.upstream_done = true;
    }
    spdlog::info("{} is done (last frame {}): final optimisation", m.service, m.last_frame_id);
    inbox.wake.notify_one();
  });
}

bool addConstraint(PoseGraph& graph, const Constraint& c, Totals& totals) {
  try {
    graph.addConstraint(c);
    return true;
  } catch (const Error& e) {
    spdlog::error("{}", e.what());
    ++totals.rejected;
    return false;
  }
}

// Applies queued keyframes and constraints in arrival order, each once;
// true when an edge was added.
bool apply(PoseGraph& graph, GraphFeed& feed, const std::vector<std::variant<KeyframeIn, Constraint>>& items,
           Totals& totals) {
  bool new_edges = false;
  for (const auto& item : items) {
    if (const auto* kf = std::get_if<KeyframeIn>(&item)) {
      if (!feed.keyframes.insert(kf->id).second) {
        ++feed.duplicates;
        continue;
      }
      try {
        graph.addKeyframe(kf->id, kf->pose_world);
      } catch (const Error& e) {
        spdlog::error("{}", e.what());
        ++totals.rejected;
      }
      continue;
    }
    const Constraint& c = std::get<Constraint>(item);
    if (!feed.constraints.emplace(static_cast<int>(c.kind), c.from_id, c.to_id).second) {
      ++feed.duplicates;
      continue;
    }
    if (!graph.hasKeyframe(c.from_id) || !graph.hasKeyframe(c.to_id)) {
      feed.waiting.push_back(c);
      continue;
    }
    new_edges |= addConstraint(graph, c, totals);
  }
  // Constraints whose keyframes have come meanwhile.
  for (auto it = feed.waiting.begin(); it != feed.waiting.end();) {
    if (graph.hasKeyframe(it->from_id) && graph.hasKeyframe(it->to_id)) {
      new_edges |= addConstraint(graph, *it, totals);
      it = feed.waiting.erase(it);
    } else {
      ++it;
    }
  }
  return new_edges;
}

void optimiseOnce(PoseGraph& graph, bool final, Totals& totals, int64_t last_frame_id, int64_t version) {
  const OptimiseReport r = graph.optimise(final);
  ++totals.optimisations;
  if (r.loop_edges_removed > 0)
    spdlog::info("removed {} outlier loop edge(s); {} loop edges kept", r.loop_edges_removed, graph.numLoopEdges());
  totals.optimise_ms += r.ms;
  totals.timing.emplace_back(last_frame_id, r.ms, graph.numKeyframes(), version);
  spdlog::debug("optimised {} keyframes / {} edges: {} iterations, cost {:.3g} -> {:.3g}, {} loop edges removed, "
                "{:.1f} ms",
                r.keyframes_optimised, r.edges_used, r.iterations, r.initial_cost, r.final_cost, r.loop_edges_removed,
                r.ms);
}

// optimiser_timing.csv in the report's format (tools/report run_files.hpp):
// one row per optimisation; frame_id is the newest tracked frame at the time.
void writeTiming(const Totals& totals, const std::string& path) {
  std::ofstream out(path);
  out << "frame_id,ms,keyframes,graph_version\n";
  for (const auto& [frame, ms, keyframes, version] : totals.timing) out << frame << ',' << ms << ',' << keyframes << ',' << version << '\n';
  if (!out) throw Error("cannot write " + path + "; check that the output folder is writable");
}

// Asks the tracker for a replay and waits for its answer; nullopt when none
// came (no tracker, or every try lost).
std::optional<rekon_msgs::replay_end_t> requestReplay(ServiceContext& ctx, Inbox& inbox, int64_t request_id) {
  rekon_msgs::replay_request_t req{};
  req.service = ctx.name();
  req.pid = getpid();
  req.request_id = request_id;
  for (int attempt = 0; attempt < kReplayTries && !ctx.stopRequested(); ++attempt) {
    ctx.bus().publish(channel::kReplayRequest, req);
    std::unique_lock<std::mutex> lock(inbox.mutex);
    const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(kReplayAnswerS));
    if (inbox.wake.wait_until(lock, deadline, [&] { return inbox.replay_end && inbox.replay_end->request_id == request_id; }))
      return inbox.replay_end;
  }
  return std::nullopt;
}

void publishFinal(Bus& bus, const rekon_msgs::graph_update_t& final_update, const rekon_msgs::done_t& done,
                  const OptimiserServiceParams& params) {
  for (int i = 0; i < params.final_repeats; ++i) {
    if (i > 0) std::this_thread::sleep_for(std::chrono::milliseconds(params.final_repeat_gap_ms));
    bus.publish(channel::kGraphUpdates, final_update);
  }
  for (int i = 0; i < params.final_repeats; ++i) {
    if (i > 0) std::this_thread::sleep_for(std::chrono::milliseconds(params.final_repeat_gap_ms));
    bus.publish(channel::kDone, done);
  }
}

}  // namespace

void runOptimiserService(ServiceContext& ctx) {
  const OptimiserServiceParams params = optimiserParamsFromConfig(ctx.config());
  Bus& bus = ctx.bus();
  Inbox inbox;
  PeerWatch peers(bus);
  StopThreadsOnExit stop_threads(ctx);  // before `inbox` dies: the bus handlers write into it
  subscribe(ctx, inbox, params.information_scale);
  peers.onNewInstance([&inbox](const std::string& service, int instance) {
    if (service != "mapper") return;
    spdlog::warn("rekon-mapper restarted (instance {})", instance);
    std::lock_guard<std::mutex> lock(inbox.mutex);
    inbox.mapper_restarted = true;
  });
  ctx.setState("running");
  spdlog::info("pose graph: information x {}, {} loss (scale {}) on loop edges, outlier chi2 > {}, {} iterations "
               "per background optimisation",
               params.information_scale, toString(params.graph.loop_loss), params.graph.loop_loss_scale,
               params.graph.loop_outlier_chi2, params.graph.max_iterations);

  PoseGraph graph(params.graph);
  GraphFeed feed;
  Totals totals;
  int64_t version = 0;
  int64_t request_id = 0;
  // A restarted optimiser finds the tracker's history in a replay. A tracker
  // still starting has no history; without a tracker (another frontend, a
  // test) nobody would answer.
  const auto wait_until = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(kTrackerSeenS));
  while (!peers.peer(kUpstreamService) && Clock::now() < wait_until && !ctx.stopRequested())
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const auto tracker = peers.peer(kUpstreamService);
  const bool tracker_has_history = tracker && tracker->instances > 0;
  if (const auto end = tracker_has_history ? requestReplay(ctx, inbox, ++request_id) : std::nullopt) {
    if (end->graph_version >= 0) {
      version = end->graph_version + kRestartVersionGap;
      spdlog::warn("the tracker has seen graph version {}: this optimiser is a restart; rebuilding from its replay "
                   "({} keyframes, {} constraints, {} tracked frames)",
                   end->graph_version, end->keyframes, end->constraints, end->tracked_frames);
    }
    // Its done_t may have gone out before we subscribed: the replay says so.
    if (end->done) {
      spdlog::info("the tracker finished before this optimiser started: final optimisation after the replay");
      std::lock_guard<std::mutex> lock(inbox.mutex);
      inbox.upstream_done = true;
    }
  }
  auto lastFrame = [&] {
    std::lock_guard<std::mutex> lock(inbox.mutex);
    return inbox.last_frame_id;
  };
  for (;;) {
    std::vector<std::variant<KeyframeIn, Constraint>> items;
    bool done = false;
    {
      std::unique_lock<std::mutex> lock(inbox.mutex);
      inbox.wake.wait_for(lock, kIdleWait, [&] { return !inbox.graph_items.empty() || inbox.upstream_done; });
      items.swap(inbox.graph_items);
      // Everything the tracker sent before its done_t is in `items` by now:
      // the bus thread queues messages in arrival order.
      done = inbox.upstream_done;
    }
    const bool new_edges = apply(graph, feed, items, totals);
    if (done || ctx.stopRequested()) break;
    if (new_edges) {
      optimiseOnce(graph, false, totals, lastFrame(), version + 1);
      bus.publish(channel::kGraphUpdates, graphUpdateMsg(graph, ++version, false));
    }
  }

  ctx.setState("finishing");
  // Fill in what was lost on the way: the tracker's totals tell whether
  // anything is missing, and a replay supplies it (each item is taken once).
  for (int round = 0; round < kReplayTries && !ctx.stopRequested() && peers.alive(kUpstreamService, PeerWatch::kSilenceS); ++round) {
    const auto end = requestReplay(ctx, inbox, ++request_id);
    std::vector<std::variant<KeyframeIn, Constraint>> items;
    {
      std::lock_guard<std::mutex> lock(inbox.mutex);
      items.swap(inbox.graph_items);
    }
    apply(graph, feed, items, totals);
    if (!end) break;  // no tracker answers (e.g. it died): optimise what we have
    size_t frames = 0;
    {
      std::lock_guard<std::mutex> lock(inbox.mutex);
      frames = inbox.frames.size();
    }
    if (static_cast<int64_t>(feed.keyframes.size()) >= end->keyframes &&
        static_cast<int64_t>(feed.constraints.size()) >= end->constraints && static_cast<int64_t>(frames) >= end->tracked_frames)
      break;
    spdlog::warn("missing after the stream: {} keyframes, {} constraints, {} tracked frames of the tracker's; "
                 "asking for them again",
                 end->keyframes - static_cast<int64_t>(feed.keyframes.size()),
                 end->constraints - static_cast<int64_t>(feed.constraints.size()),
                 end->tracked_frames - static_cast<int64_t>(frames));
  }
  if (!feed.waiting.empty())
    spdlog::error("{} constraints name a keyframe that never arrived; left out", feed.waiting.size());
  optimiseOnce(graph, true, totals, lastFrame(), version + 1);
  const rekon_msgs::graph_update_t final_update = graphUpdateMsg(graph, ++version, true);

  std::vector<TrackedFrame> frames;
  int64_t last_frame_id = -1;
  {
    std::lock_guard<std::mutex> lock(inbox.mutex);
    for (const auto& [id, f] : inbox.frames) frames.push_back(f);
    last_frame_id = inbox.last_frame_id;
    totals.rejected += inbox.rejected;
    inbox.mapper_restarted = false;  // the final update goes out now anyway
  }
  size_t missing = 0;
  const Trajectory trajectory = frameTrajectory(graph, frames, &missing);
  if (missing > 0) spdlog::error("{} tracked frames name a keyframe the graph never received; left out", missing);
  if (!ctx.outDir().empty()) {
    const std::string path = (std::filesystem::path(ctx.outDir()) / "trajectory.txt").string();
    writeTumTrajectory(trajectory, path);
    spdlog::info("wrote {} optimised frame poses to {}", trajectory.size(), path);
    writeTiming(totals, (std::filesystem::path(ctx.outDir()) / "optimiser_timing.csv").string());
  }

  rekon_msgs::done_t done_msg{};
  done_msg.service = ctx.name();
  done_msg.last_frame_id = last_frame_id;
  publishFinal(bus, final_update, done_msg, params);
  // A mapper restarted after this point still needs the final poses and our
  // done_t: stay until it is done (or gone), and send them again to each new one.
  ctx.setState("lingering");
  while (!ctx.stopRequested() && !peers.finished({"mapper"}, PeerWatch::kSilenceS)) {
    bool again = false;
    {
      std::lock_guard<std::mutex> lock(inbox.mutex);
      std::swap(again, inbox.mapper_restarted);
    }
    if (again) {
      spdlog::info("sending the final graph update and done again for the restarted mapper");
      publishFinal(bus, final_update, done_msg, params);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }

  const double n = static_cast<double>(std::max<int64_t>(totals.optimisations, 1));
  ctx.stats()
      .set("keyframes", graph.numKeyframes())
      .set("constraints", graph.numConstraints())
      .set("loop_closures", graph.numLoopEdges())
      .set("loop_edges_removed", graph.loopEdgesRemoved())
      .set("optimisations", static_cast<long long>(totals.optimisations))
      .set("optimise_ms_mean", totals.optimise_ms / n)
      .set("graph_updates", static_cast<long long>(totals.optimisations))
      .set("graph_version", static_cast<long long>(version))
      .set("duplicate_messages", static_cast<long long>(feed.duplicates))
      .set("trajectory_frames", trajectory.size())
      .set("rejected_messages", static_cast<long long>(totals.rejected));
  spdlog::info("{} keyframes, {} loop closures kept, {} removed, {} optimisations ({:.1f} ms mean)",
               graph.numKeyframes(), graph.numLoopEdges(), graph.loopEdgesRemoved(), totals.optimisations,
               totals.optimise_ms / n);
}

}  // namespace rekon::optimiser
