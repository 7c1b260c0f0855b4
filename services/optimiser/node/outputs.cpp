#include "outputs.hpp"

#include <spdlog/spdlog.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/optimiser/g2o.hpp"

namespace rekon::optimiser {
namespace {

void writeTiming(const std::vector<GraphWorker::Timing>& timing, const std::string& path) {
  std::ofstream out(path);
  out << "frame_id,ms,keyframes,graph_version\n";
  for (const auto& t : timing) out << t.last_frame_id << ',' << t.ms << ',' << t.keyframes << ',' << t.version << '\n';
  if (!out) throw Error("cannot write " + path + "; check that the output folder is writable");
}

}  // namespace

size_t writeTrajectoryAndTiming(const ServiceContext& ctx, const GraphWorker& worker,
                                const std::vector<TrackedFrame>& frames) {
  size_t missing = 0;
  const Trajectory trajectory = frameTrajectory(worker.graph(), frames, &missing);
  if (missing > 0) spdlog::error("{} tracked frames name a keyframe the graph never received; left out", missing);
  if (!ctx.outDir().empty()) {
    const std::string path = (std::filesystem::path(ctx.outDir()) / "trajectory.txt").string();
    writeTumTrajectory(trajectory, path);
    spdlog::info("wrote {} optimised frame poses to {}", trajectory.size(), path);
    writeTiming(worker.timing(), (std::filesystem::path(ctx.outDir()) / "optimiser_timing.csv").string());
  }
  return trajectory.size();
}

void setStats(ServiceContext& ctx, const GraphWorker& worker, size_t trajectory_frames) {
  const PoseGraph& graph = worker.graph();
  ctx.stats()
      .set("keyframes", graph.numKeyframes())
      .set("constraints", graph.numConstraints())
      .set("loop_closures", graph.numLoopEdges())
      .set("loop_edges_removed", graph.loopEdgesRemoved())
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
    : interval_(config.getDouble("session.graph_interval_s")) {
  const std::string dir = config.getString("session.dir");
  if (dir.empty()) return;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw Error("cannot create the session folder " + dir + " (" + ec.message() + ")");
  path_ = (std::filesystem::path(dir) / "graph.g2o").string();
}

void SessionGraph::afterOptimisation(const PoseGraph& graph, bool final) {
  const auto now = std::chrono::steady_clock::now();
  if (path_.empty() || (!final && now - last_ < interval_)) return;
  last_ = now;
  writeFileAtomically(path_, toG2o(graph));
  if (final) spdlog::info("wrote the pose graph ({} keyframes) to {}", graph.numKeyframes(), path_);
}

}  // namespace rekon::optimiser
