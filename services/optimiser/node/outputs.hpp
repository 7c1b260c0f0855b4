#pragma once
// What the optimiser leaves at the end: <out>/trajectory.txt (every tracked
// frame at its keyframe's optimised pose) and its stats (written by the
// service context). <out>/optimiser_timing.csv (a row per optimisation, in the
// report's format: tools/report run_files.hpp) grows as the run goes (GraphWorker).
#include <chrono>
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "graph_worker.hpp"
#include "rekon/common/service.hpp"
#include "rekon/optimiser/g2o.hpp"
#include "rekon/optimiser/graph_messages.hpp"

namespace rekon::optimiser {

// Every frame at its keyframe's pose in `final_update`, the poses the mapper
// gets. Returns how many frames the trajectory holds (frames whose keyframe
// the graph never received are left out, with an error in the log).
size_t writeTrajectory(const ServiceContext& ctx, const rekon_msgs::graph_update_t& final_update,
                       const std::vector<TrackedFrame>& frames);
void setStats(ServiceContext& ctx, const GraphWorker& worker, size_t trajectory_frames);

// The pose graph in the session folder (session.dir), as graph.g2o: after an
// optimisation at most every session.graph_interval_s, and after the final
// one; with session.continue, the previous run's graph is read from it first
// and the file goes on holding the whole graph (the previous run's and this one's).
class SessionGraph {
 public:
  explicit SessionGraph(const Config& config);
  // With session.continue, the graph the previous run left; nullopt without
  // one (a warning when the file is missing: that run was killed before its
  // first optimisation). rekon::Error for a corrupt or unreadable file.
  std::optional<G2oGraph> previous();
  void afterOptimisation(const PoseGraph& graph, bool final);

 private:
  std::string dir_;   // "" without a session
  std::string path_;  // "" without a session
  bool continue_ = false;
  size_t loaded_keyframes_ = 0, loaded_edges_ = 0;  // of previous(): a graph of just these is not written again
  std::chrono::duration<double> interval_;
  std::chrono::steady_clock::time_point last_{};
};

}  // namespace rekon::optimiser
