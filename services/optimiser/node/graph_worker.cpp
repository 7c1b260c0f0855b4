#include "graph_worker.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <variant>

#include "rekon/common/error.hpp"
#include "rekon/optimiser/graph_messages.hpp"

namespace rekon::optimiser {
namespace {

// The vertex that anchored the graph: the fixed one, else the lowest id.
int64_t anchorOf(const G2oGraph& g2o) {
  if (g2o.fixed) return *g2o.fixed;
  const auto lowest = std::min_element(g2o.vertices.begin(), g2o.vertices.end(),
                                       [](const auto& a, const auto& b) { return a.first < b.first; });
  return lowest->first;
}

// The anchor first, so that it anchors the graph again. The edges touching it
// last: the others link the remaining keyframes into one group that keeps its
// poses, and the first edge to the anchor moves that group rigidly by its own
// residual only (an optimisation takes that back). In file order, each edge
// would move its keyframe to where the edge alone puts it, and the session's
// optimised poses would be lost to chained odometry.
std::vector<GraphItem> inLoadOrder(const G2oGraph& g2o) {
  std::vector<GraphItem> items;
  if (g2o.vertices.empty()) return items;
  const int64_t anchor = anchorOf(g2o);
  for (const auto& [id, pose] : g2o.vertices) {
    if (id == anchor) items.insert(items.begin(), KeyframeIn{id, pose});
    else items.push_back(KeyframeIn{id, pose});
  }
  for (const bool touching_anchor : {false, true}) {
    for (const Constraint& c : g2o.edges) {
      if ((c.from_id == anchor || c.to_id == anchor) == touching_anchor) items.push_back(c);
    }
  }
  return items;
}

}  // namespace

bool GraphWorker::addConstraint(const Constraint& c, const std::string& origin) {
  try {
    graph_.addConstraint(c, origin);
    return true;
  } catch (const Error& e) {
    spdlog::error("{}", e.what());
    ++rejected_;
    return false;
  }
}

bool GraphWorker::ready(const ExternalConstraint& e) const {
  if (!graph_.hasKeyframe(e.to_id)) return false;
  return e.kind == ExternalConstraint::Kind::Prior ? graph_.anchorId().has_value() : graph_.hasKeyframe(e.from_id);
}

bool GraphWorker::addExternal(const ExternalConstraint& e) {
  const int64_t anchor = *graph_.anchorId();
  if (e.kind == ExternalConstraint::Kind::Prior && e.to_id == anchor) {
    spdlog::error("{} is on the first keyframe, which is fixed (it defines the map's world frame); dropped", e.name);
    ++rejected_;
    return false;
  }
  if (!addConstraint(edgeOf(e, anchor, *graph_.pose(anchor)), e.name)) return false;
  ++externals_added_;
  spdlog::info("added {}", e.name);
  return true;
}

bool GraphWorker::addWaitingExternals() {
  bool added = false;
  for (auto it = external_waiting_.begin(); it != external_waiting_.end();) {
    if (ready(*it)) {
      added |= addExternal(*it);
      it = external_waiting_.erase(it);
    } else {
      ++it;
    }
  }
  return added;
}

bool GraphWorker::applyExternal(const std::vector<ExternalConstraint>& constraints) {
  for (const ExternalConstraint& e : constraints) {
    if (externals_.emplace(e.source, e.sequence).second) external_waiting_.push_back(e);
    else ++duplicates_;
  }
  return addWaitingExternals();
}

bool GraphWorker::apply(const std::vector<GraphItem>& items) {
  bool new_edges = false;
  for (const auto& item : items) {
    if (const auto* kf = std::get_if<KeyframeIn>(&item)) {
      if (!keyframes_.insert(kf->id).second) {
        ++duplicates_;
        continue;
      }
      try {
        graph_.addKeyframe(kf->id, kf->pose_world);
      } catch (const Error& e) {
        spdlog::error("{}", e.what());
        ++rejected_;
      }
      continue;
    }
    const Constraint& c = std::get<Constraint>(item);
    if (!constraints_.emplace(static_cast<int>(c.kind), c.from_id, c.to_id).second) {
      ++duplicates_;
      continue;
    }
    if (!graph_.hasKeyframe(c.from_id) || !graph_.hasKeyframe(c.to_id)) {
      waiting_.push_back(c);
      continue;
    }
    new_edges |= addConstraint(c);
  }
  // Constraints whose keyframes have come meanwhile.
  for (auto it = waiting_.begin(); it != waiting_.end();) {
    if (graph_.hasKeyframe(it->from_id) && graph_.hasKeyframe(it->to_id)) {
      new_edges |= addConstraint(*it);
      it = waiting_.erase(it);
    } else {
      ++it;
    }
  }
  return addWaitingExternals() || new_edges;
}

bool GraphWorker::seen(const GraphItem& item) const {
  if (const auto* kf = std::get_if<KeyframeIn>(&item)) return keyframes_.count(kf->id) > 0;
  const Constraint& c = std::get<Constraint>(item);
  return constraints_.count({static_cast<int>(c.kind), c.from_id, c.to_id}) > 0;
}

void GraphWorker::load(const G2oGraph& g2o) { apply(inLoadOrder(g2o)); }

rekon_msgs::graph_update_t GraphWorker::optimise(bool final, int64_t last_frame_id) {
  const OptimiseReport r = graph_.optimise(final);
  ++optimisations_;
  if (r.loop_edges_removed > 0)
    spdlog::info("removed {} outlier loop edge(s); {} loop edges kept", r.loop_edges_removed, graph_.numLoopEdges());
  optimise_ms_ += r.ms;
  if (timing_) timing_->row(last_frame_id, r.ms, graph_.numKeyframes(), version_ + 1);
  spdlog::debug("optimised {} keyframes / {} edges: {} iterations, cost {:.3g} -> {:.3g}, {} loop edges removed, "
                "{:.1f} ms",
                r.keyframes_optimised, r.edges_used, r.iterations, r.initial_cost, r.final_cost, r.loop_edges_removed,
                r.ms);
  return graphUpdateMsg(graph_, ++version_, final);
}

double GraphWorker::optimiseMsMean() const {
  return optimise_ms_ / static_cast<double>(std::max<int64_t>(optimisations_, 1));
}

}  // namespace rekon::optimiser
