#include "rekon/optimiser/pose_graph.hpp"

#include <ceres/ceres.h>
#include <ceres/manifold.h>
#include <spdlog/spdlog.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <deque>
#include <set>

#include "rekon/common/error.hpp"
#include "relative_pose_cost.hpp"

namespace rekon::optimiser {
namespace {

// An information matrix whose smallest eigenvalue is below this fraction of
// its largest is treated as singular: some direction is unconstrained.
constexpr double kMaxInformationCondition = 1e12;
// Asymmetry tolerated (relative to the largest entry) before symmetrising;
// more means the sender did not compute an information matrix.
constexpr double kSymmetryTolerance = 1e-6;

std::string edgeName(const Constraint& c) {
  return std::string(c.kind == EdgeKind::Loop ? "loop" : "odometry") + " constraint " + std::to_string(c.from_id) +
         " -> " + std::to_string(c.to_id);
}

std::unique_ptr<ceres::LossFunction> makeLoss(RobustLoss loss, double scale) {
  switch (loss) {
    case RobustLoss::Cauchy: return std::make_unique<ceres::CauchyLoss>(scale);
    case RobustLoss::Huber: return std::make_unique<ceres::HuberLoss>(scale);
    case RobustLoss::None: return nullptr;
  }
  return nullptr;
}

}  // namespace

Vector6d relativePoseResidual(const Pose& from, const Pose& to, const Pose& relative) {
  const Eigen::Quaterniond qa(from.linear()), qb(to.linear()), qz(relative.linear());
  const Eigen::Vector3d ta = from.translation(), tb = to.translation();
  Vector6d e;
  detail::relativeError(qa.coeffs().data(), ta.data(), qb.coeffs().data(), tb.data(), qz.conjugate(),
                        Eigen::Vector3d(relative.translation()), e.data());
  return e;
}

PoseGraph::PoseGraph(PoseGraphParams params)
    : params_(params),
      pose_manifold_(std::make_unique<ceres::ProductManifold<ceres::EuclideanManifold<3>, ceres::EigenQuaternionManifold>>()),
      loop_loss_(makeLoss(params.loop_loss, params.loop_loss_scale)) {
  params_.validate();
}

PoseGraph::~PoseGraph() = default;

Pose PoseGraph::poseOf(const Node& n) {
  const Eigen::Quaterniond q(n.x[6], n.x[3], n.x[4], n.x[5]);
  return poseFromQuatTrans(q.normalized(), Eigen::Vector3d(n.x[0], n.x[1], n.x[2]));
}

void PoseGraph::setPose(Node& n, const Pose& p) {
  const Eigen::Quaterniond q = Eigen::Quaterniond(p.linear()).normalized();
  for (int i = 0; i < 3; ++i) n.x[i] = p.translation()[i];
  for (int i = 0; i < 4; ++i) n.x[3 + i] = q.coeffs()[i];
}

void PoseGraph::addKeyframe(int64_t id, const Pose& pose_world) {
  if (nodes_.count(id)) throw Error("keyframe " + std::to_string(id) + " is already in the pose graph; dropped");
  if (!isValidPose(pose_world, 1e-6))
    throw Error("keyframe " + std::to_string(id) + " has an invalid pose (not finite or not a rotation); dropped");
  Node& n = nodes_[id];
  setPose(n, pose_world);
  if (!anchor_) {
    anchor_ = id;
    n.attached = true;
  }
}

void PoseGraph::addConstraint(const Constraint& c) {
  const std::string name = edgeName(c);
  if (!nodes_.count(c.from_id) || !nodes_.count(c.to_id))
    throw Error(name + " names a keyframe the pose graph does not know (" +
                std::to_string(nodes_.count(c.from_id) ? c.to_id : c.from_id) + "); dropped");
  if (c.from_id == c.to_id) throw Error(name + " links a keyframe to itself; dropped");
  if (!isValidPose(c.relative, 1e-6)) throw Error(name + " has an invalid relative pose; dropped");
  const Matrix6d& info = c.information;
  if (!info.allFinite()) throw Error(name + " has a non-finite information matrix; dropped");
  const double largest = info.cwiseAbs().maxCoeff();
  if (!(largest > 0) || (info - info.transpose()).cwiseAbs().maxCoeff() > kSymmetryTolerance * largest)
    throw Error(name + " has an information matrix that is zero or not symmetric; dropped");
  const Matrix6d sym = 0.5 * (info + info.transpose());
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(sym, Eigen::EigenvaluesOnly);
  const double lo = eig.eigenvalues()[0], hi = eig.eigenvalues()[5];
  if (!(lo > 0) || hi > kMaxInformationCondition * lo)
    throw Error(name + " has an information matrix that is not positive definite (eigenvalues " + std::to_string(lo) +
                " .. " + std::to_string(hi) + "); dropped");
  const Eigen::LLT<Matrix6d> llt(sym);
  if (llt.info() != Eigen::Success) throw Error(name + " has an information matrix without a Cholesky factor; dropped");

  Edge e;
  e.c = c;
  e.c.information = sym;
  e.sqrt_information = llt.matrixU();
  const size_t index = edges_.size();
  edges_.push_back(e);
  Node& from = nodes_.at(c.from_id);
  Node& to = nodes_.at(c.to_id);
  from.edges.push_back(index);
  to.edges.push_back(index);

  if (from.attached != to.attached) {
    // Move the unattached group rigidly so that this edge holds exactly.
    const int64_t outside = from.attached ? c.to_id : c.from_id;
    const Pose target = from.attached ? Pose(poseOf(from) * c.relative) : Pose(poseOf(to) * c.relative.inverse());
    const Pose move = target * poseOf(nodes_.at(outside)).inverse();
    const std::vector<int64_t> group = unattachedGroup(outside);
    for (int64_t id : group) {
      Node& n = nodes_.at(id);
      setPose(n, orthonormalised(move * poseOf(n)));
      n.attached = true;
    }
    spdlog::debug("{} links {} keyframe(s) to the graph", name, group.size());
  }
}

std::vector<int64_t> PoseGraph::unattachedGroup(int64_t start) const {
  std::vector<int64_t> group{start};
  std::set<int64_t> seen{start};
  for (size_t i = 0; i < group.size(); ++i) {
    for (size_t ei : nodes_.at(group[i]).edges) {
      const Edge& e = edges_[ei];
      if (!e.kept) continue;
      const int64_t other = e.c.from_id == group[i] ? e.c.to_id : e.c.from_id;
      if (!nodes_.at(other).attached && seen.insert(other).second) group.push_back(other);
    }
  }
  return group;
}

void PoseGraph::recomputeAttachment() {
  for (auto& [id, n] : nodes_) n.attached = false;
  if (!anchor_) return;
  std::deque<int64_t> queue{*anchor_};
  nodes_.at(*anchor_).attached = true;
  while (!queue.empty()) {
    const int64_t id = queue.front();
    queue.pop_front();
    for (size_t ei : nodes_.at(id).edges) {
      const Edge& e = edges_[ei];
      if (!e.kept) continue;
      Node& other = nodes_.at(e.c.from_id == id ? e.c.to_id : e.c.from_id);
      if (!other.attached) {
        other.attached = true;
        queue.push_back(e.c.from_id == id ? e.c.to_id : e.c.from_id);
      }
    }
  }
}

double PoseGraph::edgeChi2(const Edge& e) const {
  const Vector6d r = relativePoseResidual(poseOf(nodes_.at(e.c.from_id)), poseOf(nodes_.at(e.c.to_id)), e.c.relative);
  return r.dot(e.c.information * r);
}

int PoseGraph::solve(bool final, OptimiseReport& report, bool first_round) {
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  int edges = 0;
  for (const Edge& e : edges_) {
    if (!e.kept) continue;
    Node& a = nodes_.at(e.c.from_id);
    Node& b = nodes_.at(e.c.to_id);
    if (!a.attached || !b.attached) continue;
    const Eigen::Quaterniond qz(e.c.relative.linear());
    auto* cost = new ceres::AutoDiffCostFunction<detail::RelativePoseCost, 6, 7, 7>(
        new detail::RelativePoseCost{qz.conjugate(), e.c.relative.translation(), e.sqrt_information});
    problem.AddResidualBlock(cost, e.c.kind == EdgeKind::Loop ? loop_loss_.get() : nullptr, a.x, b.x);
    ++edges;
  }
  report.edges_used = edges;
  int keyframes = 0;
  for (auto& [id, n] : nodes_) {
    if (!n.attached || !problem.HasParameterBlock(n.x)) continue;
    ++keyframes;
    problem.SetManifold(n.x, pose_manifold_.get());
    if (anchor_ && id == *anchor_) problem.SetParameterBlockConstant(n.x);
  }
  report.keyframes_optimised = keyframes;
  if (edges == 0) return 0;

  ceres::Solver::Options options;
  options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  options.minimizer_progress_to_stdout = false;
  options.max_num_iterations = final ? params_.final_max_iterations : params_.max_iterations;
  options.function_tolerance = final ? params_.final_function_tolerance : params_.function_tolerance;
  if (!final) options.max_solver_time_in_seconds = params_.max_solver_time_s;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  if (first_round) report.initial_cost = summary.initial_cost;
  report.final_cost = summary.final_cost;
  if (spdlog::should_log(spdlog::level::trace)) spdlog::trace("{}", summary.FullReport());
  if (summary.termination_type == ceres::FAILURE) {
    spdlog::warn("pose graph optimisation failed: {}", summary.message);
    return -1;
  }
  return static_cast<int>(summary.iterations.size());
}

OptimiseReport PoseGraph::optimise(bool final) {
  const auto start = std::chrono::steady_clock::now();
  OptimiseReport report;
  for (int round = 0;; ++round) {
    const int iterations = solve(final, report, round == 0);
    ++report.rounds;
    // A failed solve leaves the poses where they were: judging loop edges
    // there would remove the very edges that had not been applied yet.
    if (iterations < 0) break;
    report.iterations += iterations;
    if (round >= params_.outlier_rounds) break;
    int removed = 0;
    for (Edge& e : edges_) {
      if (!e.kept || e.c.kind != EdgeKind::Loop) continue;
      if (!nodes_.at(e.c.from_id).attached || !nodes_.at(e.c.to_id).attached) continue;
      const double chi2 = edgeChi2(e);
      if (chi2 > params_.loop_outlier_chi2) {
        e.kept = false;
        ++removed;
        spdlog::debug("removed outlier {} (chi2 {:.1f} > {:.1f})", edgeName(e.c), chi2, params_.loop_outlier_chi2);
      }
    }
    if (removed == 0) break;
    report.loop_edges_removed += removed;
    loop_edges_removed_ += static_cast<size_t>(removed);
    recomputeAttachment();
  }
  report.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return report;
}

std::optional<Pose> PoseGraph::pose(int64_t id) const {
  const auto it = nodes_.find(id);
  if (it == nodes_.end()) return std::nullopt;
  return poseOf(it->second);
}

std::vector<std::pair<int64_t, Pose>> PoseGraph::poses() const {
  std::vector<std::pair<int64_t, Pose>> out;
  out.reserve(nodes_.size());
  for (const auto& [id, n] : nodes_) out.emplace_back(id, poseOf(n));
  return out;
}

bool PoseGraph::isAttached(int64_t id) const {
  const auto it = nodes_.find(id);
  return it != nodes_.end() && it->second.attached;
}

size_t PoseGraph::numConstraints() const {
  return static_cast<size_t>(std::count_if(edges_.begin(), edges_.end(), [](const Edge& e) { return e.kept; }));
}

size_t PoseGraph::numLoopEdges() const {
  return static_cast<size_t>(std::count_if(edges_.begin(), edges_.end(), [](const Edge& e) {
    return e.kept && e.c.kind == EdgeKind::Loop;
  }));
}

std::vector<Constraint> PoseGraph::loopEdges() const {
  std::vector<Constraint> out;
  for (const Edge& e : edges_) {
    if (e.kept && e.c.kind == EdgeKind::Loop) out.push_back(e.c);
  }
  return out;
}

std::vector<double> PoseGraph::loopChi2() const {
  std::vector<double> out;
  for (const Edge& e : edges_) {
    if (e.kept && e.c.kind == EdgeKind::Loop) out.push_back(edgeChi2(e));
  }
  return out;
}

}  // namespace rekon::optimiser
