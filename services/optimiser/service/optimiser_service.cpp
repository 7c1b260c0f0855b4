#include "optimiser_service.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <thread>
#include <variant>
#include <vector>

#include "rekon/common/error.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon_msgs/done_t.hpp"

namespace rekon::optimiser {
namespace {

// The upstream whose done_t starts the final optimisation.
constexpr const char* kUpstreamService = "tracker";
// How often the optimisation thread looks at the stop flag when idle.
constexpr auto kIdleWait = std::chrono::milliseconds(100);

// What the bus thread hands to the optimisation thread: the handlers only
// validate and queue, so the bus thread never waits for Ceres.
struct Inbox {
  std::mutex mutex;
  std::condition_variable wake;
  std::vector<std::variant<KeyframeIn, Constraint>> graph_items;  // in arrival order
  std::vector<TrackedFrame> frames;
  bool upstream_done = false;
  int64_t last_frame_id = -1;
  int64_t rejected = 0;
};

struct Totals {
  int64_t optimisations = 0;
  double optimise_ms = 0.0;
  int64_t rejected = 0;
};

void reject(Inbox& inbox, const Error& e) {
  spdlog::error("{}", e.what());
  std::lock_guard<std::mutex> lock(inbox.mutex);
  ++inbox.rejected;
}

void subscribe(ServiceContext& ctx, Inbox& inbox, double information_scale) {
  Bus& bus = ctx.bus();
  bus.subscribe<rekon_msgs::keyframe_t>(channel::kKeyframes, [&inbox](const rekon_msgs::keyframe_t& m) {
    try {
      KeyframeIn kf = keyframeFromMsg(m);
      std::lock_guard<std::mutex> lock(inbox.mutex);
      inbox.graph_items.emplace_back(kf);
    } catch (const Error& e) {
      reject(inbox, e);
      return;
    }
    inbox.wake.notify_one();
  });
  bus.subscribe<rekon_msgs::constraint_t>(channel::kConstraints, [&inbox, information_scale](const rekon_msgs::constraint_t& m) {
    try {
      Constraint c = constraintFromMsg(m, information_scale);
      std::lock_guard<std::mutex> lock(inbox.mutex);
      inbox.graph_items.emplace_back(c);
    } catch (const Error& e) {
      reject(inbox, e);
      return;
    }
    inbox.wake.notify_one();
  });
  bus.subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFrames, [&inbox, &ctx](const rekon_msgs::tracked_frame_t& m) {
    try {
      TrackedFrame f = trackedFrameFromMsg(m);
      std::lock_guard<std::mutex> lock(inbox.mutex);
      inbox.frames.push_back(f);
      inbox.last_frame_id = std::max(inbox.last_frame_id, f.frame_id);
    } catch (const Error& e) {
      reject(inbox, e);
      return;
    }
    ctx.setLastFrame(m.frame_id);
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

// Applies queued keyframes and constraints in arrival order; true when an edge was added.
bool apply(PoseGraph& graph, const std::vector<std::variant<KeyframeIn, Constraint>>& items, Totals& totals) {
  bool new_edges = false;
  for (const auto& item : items) {
    try {
      if (const auto* kf = std::get_if<KeyframeIn>(&item)) {
        graph.addKeyframe(kf->id, kf->pose_world);
      } else {
        graph.addConstraint(std::get<Constraint>(item));
        new_edges = true;
      }
    } catch (const Error& e) {
      spdlog::error("{}", e.what());
      ++totals.rejected;
    }
  }
  return new_edges;
}

void optimiseOnce(PoseGraph& graph, bool final, Totals& totals) {
  const OptimiseReport r = graph.optimise(final);
  ++totals.optimisations;
  if (r.loop_edges_removed > 0)
    spdlog::info("removed {} outlier loop edge(s); {} loop edges kept", r.loop_edges_removed, graph.numLoopEdges());
  totals.optimise_ms += r.ms;
  spdlog::debug("optimised {} keyframes / {} edges: {} iterations, cost {:.3g} -> {:.3g}, {} loop edges removed, "
                "{:.1f} ms",
                r.keyframes_optimised, r.edges_used, r.iterations, r.initial_cost, r.final_cost, r.loop_edges_removed,
                r.ms);
}

}  // namespace

void runOptimiserService(ServiceContext& ctx) {
  const OptimiserServiceParams params = optimiserParamsFromConfig(ctx.config());
  Bus& bus = ctx.bus();
  Inbox inbox;
  StopThreadsOnExit stop_threads(ctx);  // before `inbox` dies: the bus handlers write into it
  subscribe(ctx, inbox, params.information_scale);
  ctx.setState("running");
  spdlog::info("pose graph: information x {}, {} loss (scale {}) on loop edges, outlier chi2 > {}, {} iterations "
               "per background optimisation",
               params.information_scale, toString(params.graph.loop_loss), params.graph.loop_loss_scale,
               params.graph.loop_outlier_chi2, params.graph.max_iterations);

  PoseGraph graph(params.graph);
  Totals totals;
  int64_t version = 0;
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
    const bool new_edges = apply(graph, items, totals);
    if (done || ctx.stopRequested()) break;
    if (new_edges) {
      optimiseOnce(graph, false, totals);
      bus.publish(channel::kGraphUpdates, graphUpdateMsg(graph, ++version, false));
    }
  }

  ctx.setState("finishing");
  optimiseOnce(graph, true, totals);
  const rekon_msgs::graph_update_t final_update = graphUpdateMsg(graph, ++version, true);
  for (int i = 0; i < params.final_repeats; ++i) {
    if (i > 0) std::this_thread::sleep_for(std::chrono::milliseconds(params.final_repeat_gap_ms));
    bus.publish(channel::kGraphUpdates, final_update);
  }

  std::vector<TrackedFrame> frames;
  int64_t last_frame_id = -1;
  {
    std::lock_guard<std::mutex> lock(inbox.mutex);
    frames = inbox.frames;
    last_frame_id = inbox.last_frame_id;
    totals.rejected += inbox.rejected;
  }
  size_t missing = 0;
  const Trajectory trajectory = frameTrajectory(graph, frames, &missing);
  if (missing > 0) spdlog::error("{} tracked frames name a keyframe the graph never received; left out", missing);
  if (!ctx.outDir().empty()) {
    const std::string path = (std::filesystem::path(ctx.outDir()) / "trajectory.txt").string();
    writeTumTrajectory(trajectory, path);
    spdlog::info("wrote {} optimised frame poses to {}", trajectory.size(), path);
  }

  rekon_msgs::done_t done_msg{};
  done_msg.service = ctx.name();
  done_msg.last_frame_id = last_frame_id;
  for (int i = 0; i < params.final_repeats; ++i) {
    if (i > 0) std::this_thread::sleep_for(std::chrono::milliseconds(params.final_repeat_gap_ms));
    bus.publish(channel::kDone, done_msg);
  }

  const double n = static_cast<double>(std::max<int64_t>(totals.optimisations, 1));
  ctx.stats()
      .set("keyframes", graph.numKeyframes())
      .set("constraints", graph.numConstraints())
      .set("loop_closures", graph.numLoopEdges())
      .set("loop_edges_removed", graph.loopEdgesRemoved())
      .set("optimisations", static_cast<long long>(totals.optimisations))
      .set("optimise_ms_mean", totals.optimise_ms / n)
      .set("graph_updates", static_cast<long long>(version))
      .set("trajectory_frames", trajectory.size())
      .set("rejected_messages", static_cast<long long>(totals.rejected));
  spdlog::info("{} keyframes, {} loop closures kept, {} removed, {} optimisations ({:.1f} ms mean)",
               graph.numKeyframes(), graph.numLoopEdges(), graph.loopEdgesRemoved(), totals.optimisations,
               totals.optimise_ms / n);
}

}  // namespace rekon::optimiser
