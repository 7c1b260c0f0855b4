#pragma once
// The pose graph the optimisation thread feeds from the inbox. Keyframes and
// constraints arrive live and again in replays: each is added once, and a
// constraint whose keyframes have not arrived (lost on the way) waits for
// them. Optimisations are counted and timed for the outputs.
#include <cstdint>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <tuple>
#include <vector>

#include "inbox.hpp"
#include "rekon/common/csv_log.hpp"
#include "rekon/optimiser/g2o.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon_msgs/graph_update_t.hpp"

namespace rekon::optimiser {

class GraphWorker {
 public:
  explicit GraphWorker(const PoseGraphParams& params) : graph_(params) {}

  // Each optimisation from now on is a row of `path` as it happens
  // (frame_id: the newest tracked frame then, ms, keyframes, graph_version;
  // the report reads it), added to the killed instance's rows for a
  // restarted optimiser: a long or killed run keeps them all.
  void logTimingTo(const std::string& path, bool append) {
    timing_.emplace(path, "frame_id,ms,keyframes,graph_version", append);
  }

  // Adds queued keyframes and constraints in arrival order, each once; true
  // when an edge was added.
  bool apply(const std::vector<GraphItem>& items);
  // Adds external constraints, each once (by source and sequence); one whose
  // keyframes have not arrived waits for them. True when an edge was added.
  bool applyExternal(const std::vector<ExternalConstraint>& constraints);
  // A previous run's graph (session.continue), before anything is applied:
  // the fixed vertex first (else the lowest id) so that it anchors the graph
  // again, then the other vertices, then the edges (those touching the anchor
  // last, so that the keyframes keep the session's poses), each taken as if
  // it had arrived: the same keyframe or constraint arriving later (in a
  // tracker's replay) is a duplicate.
  void load(const G2oGraph& g2o);
  // Optimises (the bounded background budget, or the final one) and returns
  // the graph update, numbered with the next version.
  rekon_msgs::graph_update_t optimise(bool final, int64_t last_frame_id);
  // A restarted optimiser numbers its updates past what consumers have seen.
  void continueVersionsAfter(int64_t version) { version_ = version; }
  void countRejected(int64_t n) { rejected_ += n; }

  const PoseGraph& graph() const { return graph_; }
  // The keyframe or constraint has been applied before (a duplicate now).
  bool seen(const GraphItem& item) const;
  size_t keyframesSeen() const { return keyframes_.size(); }
  size_t constraintsSeen() const { return constraints_.size(); }
  size_t constraintsWaiting() const { return waiting_.size() + external_waiting_.size(); }
  int64_t externalConstraintsAdded() const { return externals_added_; }
  int64_t duplicates() const { return duplicates_; }
  int64_t optimisations() const { return optimisations_; }
  double optimiseMsMean() const;
  int64_t rejected() const { return rejected_; }
  int64_t version() const { return version_; }

 private:
  bool addConstraint(const Constraint& c, const std::string& origin = "");
  // An external constraint once its keyframes (and, for a prior, the anchor) are in the graph.
  bool addExternal(const ExternalConstraint& e);
  bool ready(const ExternalConstraint& e) const;
  bool addWaitingExternals();

  PoseGraph graph_;
  std::set<int64_t> keyframes_;
  std::set<std::tuple<int, int64_t, int64_t>> constraints_;  // kind, from, to
  std::vector<Constraint> waiting_;
  std::set<std::pair<std::string, int64_t>> externals_;  // source, sequence
  std::vector<ExternalConstraint> external_waiting_;
  int64_t externals_added_ = 0;
  int64_t duplicates_ = 0;
  int64_t optimisations_ = 0;
  double optimise_ms_ = 0.0;
  int64_t rejected_ = 0;
  int64_t version_ = 0;
  std::optional<CsvLog> timing_;
};

}  // namespace rekon::optimiser
