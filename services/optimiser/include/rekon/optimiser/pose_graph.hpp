#pragma once
// The keyframe pose graph of DVO-SLAM's back end, optimised with Ceres:
// keyframe poses on SE(3) (a translation plus a unit quaternion on Ceres'
// EigenQuaternionManifold, one parameter block per keyframe), relative-pose edges weighted by the square root of
// their information matrices, a robust loss on loop edges only, the first
// keyframe fixed. Loop edges that remain outliers after an optimisation are
// removed and the graph re-optimised.
//
// Keyframes that no chain of edges links to the first one (after a tracking
// reset) keep the pose they were added with; when an edge links them, their
// whole group is moved rigidly so that the edge holds, and then optimised.
//
// With culling (params cull_radius_m > 0) the graph is bounded by the space,
// not the time: a keyframe that has settled (kCullWindow newer ones arrived)
// and lies near an older kept keyframe it has an edge to is culled, that is
// attached rigidly to it at their current relative pose. Its edges move to the
// kept keyframe, their information carried by the adjoint, and edges that then
// join the same two keyframes (same kind, the frontend's own) are merged into
// one. A culled keyframe's pose is still derived (pose(), poses()), and edges
// that arrive later naming it land on its kept keyframe. Edges removed as
// outliers are dropped, not only marked.
#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "rekon/common/pose.hpp"
#include "rekon/common/se3.hpp"
#include "rekon/optimiser/params.hpp"

namespace ceres {
class LossFunction;
class Manifold;
}  // namespace ceres

namespace rekon::optimiser {

namespace detail {
struct RelativeMeasurement;
class BlockCholesky;
}  // namespace detail

enum class EdgeKind { Odometry, Loop };

// Pose of keyframe `to_id` in the frame of `from_id` (from^-1 * to), with the
// information of the right perturbation xi = (v, w): to-in-from = relative * exp(xi),
// translation part first, as the tracker computes it.
struct Constraint {
  EdgeKind kind = EdgeKind::Odometry;
  int64_t from_id = 0;
  int64_t to_id = 0;
  Pose relative = Pose::Identity();
  Matrix6d information = Matrix6d::Identity();
};

// The edge's error in (v, w) order: E = relative^-1 * from^-1 * to, as
// (translation of E, 2 * vector part of E's quaternion). To first order this
// is the xi of to-in-from = relative * exp(xi), the tracker's convention.
Vector6d relativePoseResidual(const Pose& from, const Pose& to, const Pose& relative);

struct OptimiseReport {
  int iterations = 0;            // over all rounds
  int rounds = 0;                // solves (1 + re-optimisations after removing outliers)
  int loop_edges_removed = 0;
  int keyframes_optimised = 0;   // linked to the first keyframe
  int edges_used = 0;
  double initial_cost = 0.0;     // 0.5 * sum of (robustified) squared whitened residuals
  double final_cost = 0.0;
  double ms = 0.0;               // wall time of the whole call
  double cpu_ms = 0.0;           // CPU time of the calling thread (what a loaded machine does not inflate)
};

class PoseGraph {
 public:
  explicit PoseGraph(PoseGraphParams params = {});
  ~PoseGraph();
  PoseGraph(const PoseGraph&) = delete;
  PoseGraph& operator=(const PoseGraph&) = delete;

  // Throws rekon::Error for a duplicate id or an invalid pose. The first
  // keyframe added is the fixed anchor.
  void addKeyframe(int64_t id, const Pose& pose_world);
  // Throws rekon::Error for unknown keyframe ids, a self edge, an invalid
  // relative pose, or an information matrix that is not finite, symmetric
  // and positive definite. `origin` names an external constraint (who sent
  // what) in every line about it, and its removal as an outlier is a warning;
  // "" for the frontend's own.
  void addConstraint(const Constraint& constraint, const std::string& origin = "");

  // Warm-started from the current poses. `final` uses final_max_iterations
  // and no time limit instead of the bounded background budget.
  OptimiseReport optimise(bool final = false);

  // Kept or culled.
  bool hasKeyframe(int64_t id) const { return nodes_.count(id) > 0 || culled_.count(id) > 0; }
  std::optional<Pose> pose(int64_t id) const;
  // Every keyframe's current estimate (culled ones derived), ascending id.
  std::vector<std::pair<int64_t, Pose>> poses() const;
  // Linked to the first keyframe by a chain of (kept) edges.
  bool isAttached(int64_t id) const;
  std::optional<int64_t> anchorId() const { return anchor_; }

  size_t numKeyframes() const { return nodes_.size() + culled_.size(); }
  size_t numCulled() const { return culled_.size(); }
  // Edges merged into another one between the same keyframes, and edges
  // dropped because culling put both their ends on one keyframe.
  size_t edgesMerged() const { return edges_merged_; }
  size_t edgesDroppedByCulling() const { return edges_dropped_by_culling_; }
  // Moved loop edges past loop_neighbours_max: re-routed onto an existing pair, or dropped (no neighbour near).
  size_t edgesRerouted() const { return edges_rerouted_; }
  size_t edgesDroppedByCap() const { return edges_dropped_by_cap_; }
  size_t numConstraints() const;  // kept ones
  size_t numLoopEdges() const;    // kept loop edges
  size_t loopEdgesRemoved() const { return loop_edges_removed_; }
  // The kept loop edges, in insertion order.
  std::vector<Constraint> loopEdges() const;
  // Every kept edge (odometry and loop), in insertion order.
  std::vector<Constraint> constraints() const;
  // Per culled keyframe, an odometry edge from the keyframe it was culled onto
  // that holds its frozen pose there, stiff (1e10): what a
  // session's graph.g2o keeps of culling, so that a continued session moves
  // the culled keyframes with their kept ones. Ascending culled id.
  std::vector<Constraint> cullLinks() const;
  // chi2 = r^T I r of every kept loop edge at the current poses, in insertion order.
  std::vector<double> loopChi2() const;
  const PoseGraphParams& params() const { return params_; }

 private:
  struct Node {
    // One Ceres parameter block: translation, then the unit quaternion in
    // Eigen's order (x, y, z, w), on a product manifold R^3 x S^3.
    double x[7];
    bool attached = false;
    std::vector<size_t> edges;
  };
  struct Edge {
    Constraint c;
    std::string origin;
    Matrix6d sqrt_information;  // upper triangular U with U^T U = information
    std::shared_ptr<const detail::RelativeMeasurement> z;
    bool kept = true;
    bool moved = false;  // put on its keyframes by culling (a revisit's edge moved onto kept keyframes)
  };

  // A culled keyframe: its pose in the kept keyframe it was attached to.
  struct Culled {
    int64_t kept;
    Pose in_kept;
  };

  static Pose poseOf(const Node& n);
  // The information matrix checked (rekon::Error otherwise) and symmetrised.
  static Matrix6d checkedInformation(const Constraint& c, const std::string& name);
  // The edge as the solver uses it (its square-root information, its measurement).
  static Edge makeEdge(const Constraint& c, const std::string& origin, bool moved = false);
  void insertEdge(const Constraint& c, const std::string& origin, const std::string& name, bool moved);
  // The kept keyframe `id` is (or is attached to) and id's pose in it.
  std::pair<int64_t, Pose> resolve(int64_t id) const;
  // The constraint between the kept keyframes its ends are on, its information carried along.
  Constraint onKeptKeyframes(const Constraint& c) const;
  // Culling (see the top of this file), after an optimisation.
  void cullSettledKeyframes();
  std::optional<int64_t> cullTarget(int64_t id) const;
  void cull(int64_t id, int64_t kept);
  // Drops removed edges, merges edges between the same keyframes (culling
  // only), holds each kept keyframe to loop_neighbours_max pairs made by
  // moved loop edges, and rebuilds each node's edge list.
  void compactEdges();
  // Per kept keyframe, the keyframes its loop edges pair it with, and how
  // many of those pairs moved edges made.
  struct LoopNeighbours {
    std::vector<int64_t> ids;
    size_t moved = 0;
  };
  // A loop edge between settled keyframes that pairs them for the first
  // time, held to loop_neighbours_max: true when it stays (noted in
  // `neighbours`) or was re-routed onto a pair that has an edge (`e` then
  // joins that pair), false when it is to be dropped.
  bool capMovedLoopEdge(Edge& e, std::unordered_map<int64_t, LoopNeighbours>& neighbours) const;
  // A moved loop edge past loop_neighbours_max, re-routed onto a pair `end`
  // has already (its other end swapped for end's neighbour nearest to it,
  // within kRerouteRadiusM, rigidly at their current relative pose); nullopt
  // when no neighbour is that near.
  std::optional<Constraint> rerouted(const Constraint& c, int64_t end, const std::vector<int64_t>& neighbours) const;
  bool mergeable(const Edge& e) const;
  static void setPose(Node& n, const Pose& p);
  double edgeChi2(const Edge& e) const;
  static std::string nameOf(const Edge& e);
  // The unattached keyframes linked to `start` by kept edges.
  std::vector<int64_t> unattachedGroup(int64_t start) const;
  void recomputeAttachment();
  // One solve over the attached keyframes with params_.solver; returns
  // iterations, -1 when the solver failed (the poses are unchanged then).
  int solve(bool final, OptimiseReport& report, bool first_round);
  int solveCeres(bool final, OptimiseReport& report, bool first_round);
  int solveBlockCholesky(bool final, OptimiseReport& report, bool first_round);
  // cholesky_, analysed for n variables and these pairs (kept while they do not change).
  detail::BlockCholesky& analysedCholesky(int n, const std::vector<std::pair<int, int>>& pairs);

  PoseGraphParams params_;
  std::map<int64_t, Node> nodes_;
  // A deque, not a vector: an edge is ~800 bytes and a long scan has thousands
  // (3-lap corridor: 6 853), so a vector's doubling kept up to half its
  // capacity unused and briefly held both copies while growing.
  std::deque<Edge> edges_;
  std::optional<int64_t> anchor_;
  size_t loop_edges_removed_ = 0;
  std::map<int64_t, Culled> culled_;
  std::deque<int64_t> unjudged_;  // keyframes not yet judged for culling, oldest first (culling only)
  bool compact_ = false;          // an edge was removed, moved or redirected since the last compactEdges
  size_t edges_merged_ = 0, edges_dropped_by_culling_ = 0, edges_rerouted_ = 0, edges_dropped_by_cap_ = 0;
  std::unique_ptr<ceres::Manifold> pose_manifold_;
  std::unique_ptr<ceres::LossFunction> loop_loss_;
  std::unique_ptr<detail::BlockCholesky> cholesky_;  // with the pattern it was analysed for
  std::vector<std::pair<int, int>> cholesky_pairs_;
};

}  // namespace rekon::optimiser
