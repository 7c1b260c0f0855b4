#include "outputs.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/common/pose.hpp"

namespace rekon::optimiser {
namespace {

// A restarted optimiser's trajectory replaces the one its predecessor wrote
// only when it covers at least as many frames (a replay cut short by a
// vanished tracker must not undo a complete run). Every file is written
// beside and renamed (writeTumTrajectory), so a kill never leaves half of one.
bool keepsTheBetter(const ServiceContext& ctx, const Trajectory& trajectory, const std::filesystem::path& path) {
  if (!ctx.config().getBool("optimiser.restarted") || !std::filesystem::exists(path)) return true;
  size_t before = 0;
  try {
    before = readTumTrajectory(path.string()).size();
  } catch (const Error& e) {
    spdlog::warn("the earlier {} is unreadable ({}); replacing it", path.string(), e.what());
    return true;
  }
  if (trajectory.size() >= before) {
    spdlog::info("restarted: {} frame poses replace the {} the earlier instance wrote", trajectory.size(), before);
    return true;
  }
  spdlog::warn("restarted: this instance has {} frame poses, the earlier instance's {} has {}; kept that one",
               trajectory.size(), path.string(), before);
  return false;
}

}  // namespace

size_t writeTrajectory(const ServiceContext& ctx, const rekon_msgs::graph_update_t& final_update,
                       const std::vector<TrackedFrame>& frames) {
  size_t missing = 0;
  const Trajectory trajectory = frameTrajectory(graphPoses(final_update), frames, &missing);
  if (missing > 0) spdlog::error("{} tracked frames name a keyframe the graph never received; left out", missing);
  if (ctx.outDir().empty()) return trajectory.size();
  const std::filesystem::path path = std::filesystem::path(ctx.outDir()) / "trajectory.txt";
  if (!keepsTheBetter(ctx, trajectory, path)) return trajectory.size();
  writeTumTrajectory(trajectory, path.string());
  spdlog::info("wrote {} optimised frame poses to {}", trajectory.size(), path.string());
  return trajectory.size();
}

void setStats(ServiceContext& ctx, const GraphWorker& worker, size_t trajectory_frames) {
  const PoseGraph& graph = worker.graph();
  ctx.stats()
      .set("keyframes", graph.numKeyframes())
      .set("constraints", graph.numConstraints())
      .set("loop_closures", graph.numLoopEdges())
      .set("external_constraints", static_cast<long long>(worker.externalConstraintsAdded()))
      .set("loop_edges_removed", graph.loopEdgesRemoved())
      .set("keyframes_culled", graph.numCulled())
      .set("edges_merged", graph.edgesMerged())
      .set("edges_dropped_by_culling", graph.edgesDroppedByCulling())
      .set("edges_rerouted", graph.edgesRerouted())
      .set("edges_dropped_by_cap", graph.edgesDroppedByCap())
      .set("optimisations", static_cast<long long>(worker.optimisations()))
      .set("optimise_ms_mean", worker.optimiseMsMean())
      .set("graph_updates", static_cast<long long>(worker.optimisations()))
      .set("graph_version", static_cast<long long>(worker.version()))
      .set("duplicate_messages", static_cast<long long>(worker.duplicates()))
      .set("trajectory_frames", trajectory_frames)
      .set("rejected_messages", static_cast<long long>(worker.rejected()));
  spdlog::info("{} keyframes, {} loop closures kept, {} removed, {} optimisations ({:.1f} ms mean)",
               graph.numKeyframes(), graph.numLoopEdges(), graph.loopEdgesRemoved(), worker.optimisations(),
               worker.optimiseMsMean());
}

SessionGraph::SessionGraph(const Config& config)
    : dir_(config.getString("session.dir")),
      continue_(config.getBool("session.continue")),
      interval_(config.getDouble("session.graph_interval_s")) {
  if (dir_.empty()) return;
  std::error_code ec;
  std::filesystem::create_directories(dir_, ec);
  if (ec) throw Error("cannot create the session folder " + dir_ + " (" + ec.message() + ")");
  path_ = (std::filesystem::path(dir_) / "graph.g2o").string();
}

std::optional<G2oGraph> SessionGraph::previous() {
  if (!continue_ || path_.empty()) return std::nullopt;
  if (!std::filesystem::exists(path_)) {
    spdlog::warn("session {}: no graph.g2o (the run was stopped before its first optimisation); the pose graph "
                 "starts empty",
                 dir_);
    return std::nullopt;
  }
  G2oGraph graph = readG2oFile(path_);
  loaded_keyframes_ = graph.vertices.size();
  loaded_edges_ = graph.edges.size();
  const auto loops = std::count_if(graph.edges.begin(), graph.edges.end(),
                                   [](const Constraint& c) { return c.kind == EdgeKind::Loop; });
  spdlog::info("session {}: loaded {} keyframes, {} odometry and {} loop edges from graph.g2o", dir_,
               graph.vertices.size(), static_cast<long>(graph.edges.size()) - loops, loops);
  return graph;
}

void SessionGraph::afterOptimisation(const PoseGraph& graph, bool final) {
  const auto now = std::chrono::steady_clock::now();
  if (path_.empty() || (!final && now - last_ < interval_)) return;
  // The previous run's graph alone, re-optimised: the file keeps it as it was
  // (a continued run that adds nothing, or stops early, leaves the session untouched).
  if (graph.numKeyframes() == loaded_keyframes_ && graph.numConstraints() == loaded_edges_) return;
  last_ = now;
  writeFileAtomically(path_, toG2o(graph));
  if (final) spdlog::info("wrote the pose graph ({} keyframes) to {}", graph.numKeyframes(), path_);
}

}  // namespace rekon::optimiser
