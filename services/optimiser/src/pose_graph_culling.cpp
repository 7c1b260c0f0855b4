// Keyframe culling of the pose graph (pose_graph.hpp, issue 49): culled
// keyframes resolved to the kept ones, edges carried onto them with the
// adjoint, merged, and the edge list compacted.
#include <spdlog/spdlog.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <map>
#include <limits>
#include <tuple>
#include <unordered_map>

#include "rekon/common/se3.hpp"
#include "rekon/optimiser/pose_graph.hpp"

namespace rekon::optimiser {

std::pair<int64_t, Pose> PoseGraph::resolve(int64_t id) const {
  Pose in_kept = Pose::Identity();
  for (auto it = culled_.find(id); it != culled_.end(); it = culled_.find(id)) {
    in_kept = it->second.in_kept * in_kept;
    id = it->second.kept;
  }
  return {id, in_kept};
}

namespace {

// The constraint between `from` and `to`, where its own ends are from * in_from and to * in_to. With
// from = F T_f and to = T T_t: T-in-F = T_f relative T_t^-1, and the edge's error E = T_t^-1 E' T_t, so
// xi' = Ad(T_t) xi: I' = Ad(T_t^-1)^T I Ad(T_t^-1).
Constraint onOtherEnds(const Constraint& c, int64_t from, const Pose& in_from, int64_t to, const Pose& in_to) {
  Constraint out = c;
  out.from_id = from;
  out.to_id = to;
  out.relative = orthonormalised(in_from * c.relative * in_to.inverse());
  const Matrix6d ad = adjoint(in_to.inverse());
  out.information = ad.transpose() * c.information * ad;
  out.information = 0.5 * (out.information + out.information.transpose()).eval();
  return out;
}

}  // namespace

Constraint PoseGraph::onKeptKeyframes(const Constraint& c) const {
  const auto [from, in_from] = resolve(c.from_id);
  const auto [to, in_to] = resolve(c.to_id);
  return onOtherEnds(c, from, in_from, to, in_to);
}

void PoseGraph::cullSettledKeyframes() {
  while (unjudged_.size() > static_cast<size_t>(PoseGraphParams::kCullWindow)) {
    const int64_t id = unjudged_.front();
    unjudged_.pop_front();
    if (const std::optional<int64_t> kept = cullTarget(id)) cull(id, *kept);
  }
}

std::optional<int64_t> PoseGraph::cullTarget(int64_t id) const {
  const auto it = nodes_.find(id);
  if (it == nodes_.end() || !it->second.attached || id == anchor_) return std::nullopt;
  const Pose pose = poseOf(it->second);
  const double max_angle = params_.cull_angle_deg * M_PI / 180.0;
  // Only onto a keyframe at least the window older: a revisit, never a neighbour of the same pass (culling
  // those froze what one pass's loop edges average: 7scenes_loop_1000's ATE rose 4.4 % at 0.3 m). The
  // oldest in reach, not the nearest: a revisit goes onto the first visit's keyframe rather than onto a
  // later visit's, so that the kept keyframes are those of the first visit to each place.
  std::optional<int64_t> oldest;
  for (size_t ei : it->second.edges) {
    const Edge& e = edges_[ei];
    const int64_t other = e.c.from_id == id ? e.c.to_id : e.c.from_id;
    if (!e.kept || other > id - PoseGraphParams::kCullWindow || (oldest && other > *oldest)) continue;
    const Pose other_pose = poseOf(nodes_.at(other));
    if (translationDistance(pose, other_pose) < params_.cull_radius_m && rotationAngle(pose, other_pose) < max_angle)
      oldest = other;
  }
  return oldest;
}

void PoseGraph::cull(int64_t id, int64_t kept) {
  culled_[id] = Culled{kept, Pose(poseOf(nodes_.at(kept)).inverse() * poseOf(nodes_.at(id)))};
  for (size_t ei : nodes_.at(id).edges) {
    Edge& e = edges_[ei];
    if (!e.kept) continue;
    const Constraint moved = onKeptKeyframes(e.c);
    if (moved.from_id == moved.to_id) {
      e.kept = false;
      ++edges_dropped_by_culling_;
      continue;
    }
    e = makeEdge(moved, e.origin, true);
  }
  nodes_.erase(id);
  compact_ = true;
  spdlog::debug("keyframe {} culled onto keyframe {}", id, kept);
}

std::vector<Constraint> PoseGraph::cullLinks() const {
  // Rigid next to any measurement (1e-5 m and rad; the tracker's edges weigh 1e4-1e6) and still well
  // conditioned in the block Cholesky.
  const double stiff = 1e10;
  std::vector<Constraint> out;
  for (const auto& [id, c] : culled_) {
    Constraint link;
    link.kind = EdgeKind::Odometry;
    link.from_id = c.kept;
    link.to_id = id;
    link.relative = c.in_kept;
    link.information = stiff * Matrix6d::Identity();
    out.push_back(link);
  }
  return out;
}

bool PoseGraph::mergeable(const Edge& e) const { return params_.cull_radius_m > 0 && e.origin.empty(); }

namespace {

// Two measurements of the same relative pose (b brought to a's direction)
// as one: a Gaussian fusion in a's tangent space, to first order.
Constraint merged(const Constraint& a, const Constraint& b) {
  Pose relative = b.relative;
  Matrix6d information = b.information;
  if (b.from_id != a.from_id) {
    // from-in-to = relative^-1 exp(-Ad(relative) xi): I'' = Ad(relative^-1)^T I Ad(relative^-1).
    const Matrix6d ad = adjoint(b.relative.inverse());
    relative = b.relative.inverse();
    information = ad.transpose() * b.information * ad;
  }
  Constraint out = a;
  out.information = a.information + information;
  out.information = 0.5 * (out.information + out.information.transpose()).eval();
  const Vector6d d = logSe3(Pose(a.relative.inverse() * relative));
  const Vector6d x = out.information.ldlt().solve(information * d);
  out.relative = orthonormalised(a.relative * expSe3(x));
  return out;
}

}  // namespace

std::optional<Constraint> PoseGraph::rerouted(const Constraint& c, int64_t end,
                                               const std::vector<int64_t>& neighbours) const {
  const int64_t far = c.from_id == end ? c.to_id : c.from_id;
  const Pose far_pose = poseOf(nodes_.at(far));
  std::optional<int64_t> nearest;
  double nearest_m = PoseGraphParams::kRerouteRadiusM;
  for (int64_t n : neighbours) {
    const double d = translationDistance(poseOf(nodes_.at(n)), far_pose);
    if (d < nearest_m) nearest_m = d, nearest = n;
  }
  if (!nearest) return std::nullopt;
  const Pose far_in_nearest(poseOf(nodes_.at(*nearest)).inverse() * far_pose);
  if (c.from_id == end) return onOtherEnds(c, end, Pose::Identity(), *nearest, far_in_nearest);
  return onOtherEnds(c, *nearest, far_in_nearest, end, Pose::Identity());
}

bool PoseGraph::capMovedLoopEdge(Edge& e, std::unordered_map<int64_t, LoopNeighbours>& neighbours) const {
  const size_t max = static_cast<size_t>(params_.loop_neighbours_max);
  LoopNeighbours& from = neighbours[e.c.from_id];
  LoopNeighbours& to = neighbours[e.c.to_id];
  if (!e.moved || (from.moved < max && to.moved < max)) {
    from.ids.push_back(e.c.to_id);
    to.ids.push_back(e.c.from_id);
    from.moved += e.moved;
    to.moved += e.moved;
    return true;
  }
  std::optional<Constraint> onto;
  if (from.moved >= max) onto = rerouted(e.c, e.c.from_id, from.ids);
  if (!onto && to.moved >= max) onto = rerouted(e.c, e.c.to_id, to.ids);
  if (!onto) return false;
  e = makeEdge(*onto, e.origin, true);  // onto a pair that has an edge: the caller merges it into that one
  return true;
}

void PoseGraph::compactEdges() {
  std::deque<Edge> kept;
  std::map<std::tuple<int, int64_t, int64_t>, size_t> by_pair;  // kind, lower id, higher id
  std::unordered_map<int64_t, LoopNeighbours> neighbours;
  // Keyframes still young (not yet judged for culling) are not held to the cap: their own loop edges judge them.
  const int64_t young = unjudged_.empty() ? std::numeric_limits<int64_t>::max() : unjudged_.front();
  const auto pairKey = [](const Constraint& c) {
    return std::make_tuple(static_cast<int>(c.kind), std::min(c.from_id, c.to_id), std::max(c.from_id, c.to_id));
  };
  for (Edge& e : edges_) {
    if (!e.kept) continue;
    if (mergeable(e)) {
      if (params_.loop_neighbours_max > 0 && e.c.kind == EdgeKind::Loop && e.c.from_id < young &&
          e.c.to_id < young && by_pair.count(pairKey(e.c)) == 0) {
        const int64_t from = e.c.from_id, to = e.c.to_id;
        if (!capMovedLoopEdge(e, neighbours)) {
          ++edges_dropped_by_cap_;
          continue;
        }
        edges_rerouted_ += e.c.from_id != from || e.c.to_id != to;
      }
      const auto [it, fresh] = by_pair.emplace(pairKey(e.c), kept.size());
      if (!fresh) {
        Edge& into = kept[it->second];
        into = makeEdge(merged(into.c, e.c), into.origin, into.moved);
        ++edges_merged_;
        continue;
      }
    }
    kept.push_back(std::move(e));
  }
  edges_.swap(kept);
  for (auto& [id, n] : nodes_) n.edges.clear();
  for (size_t i = 0; i < edges_.size(); ++i) {
    nodes_.at(edges_[i].c.from_id).edges.push_back(i);
    nodes_.at(edges_[i].c.to_id).edges.push_back(i);
  }
  compact_ = false;
}

}  // namespace rekon::optimiser
