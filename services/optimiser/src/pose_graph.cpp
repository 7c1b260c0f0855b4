#include "rekon/optimiser/pose_graph.hpp"

#include <ceres/ceres.h>
#include <ceres/manifold.h>
#include <spdlog/spdlog.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <set>

#include "block_cholesky.hpp"
#include "rekon/common/cpu_time.hpp"
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
  if (hasKeyframe(id)) throw Error("keyframe " + std::to_string(id) + " is already in the pose graph; dropped");
  if (!isValidPose(pose_world, 1e-6))
    throw Error("keyframe " + std::to_string(id) + " has an invalid pose (not finite or not a rotation); dropped");
  Node& n = nodes_[id];
  setPose(n, pose_world);
  if (!anchor_) {
    anchor_ = id;
    n.attached = true;
  }
  if (params_.cull_radius_m > 0) unjudged_.push_back(id);
}

std::string PoseGraph::nameOf(const Edge& e) { return e.origin.empty() ? edgeName(e.c) : e.origin; }

Matrix6d PoseGraph::checkedInformation(const Constraint& c, const std::string& name) {
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
  if (Eigen::LLT<Matrix6d>(sym).info() != Eigen::Success)
    throw Error(name + " has an information matrix without a Cholesky factor; dropped");
  return sym;
}

PoseGraph::Edge PoseGraph::makeEdge(const Constraint& c, const std::string& origin, bool moved) {
  Edge e;
  e.c = c;
  e.origin = origin;
  e.moved = moved;
  e.sqrt_information = Eigen::LLT<Matrix6d>(c.information).matrixU();
  e.z = std::make_shared<detail::RelativeMeasurement>(Eigen::Quaterniond(c.relative.linear()).conjugate(),
                                                      c.relative.translation());
  return e;
}

void PoseGraph::addConstraint(const Constraint& c, const std::string& origin) {
  const std::string name = origin.empty() ? edgeName(c) : origin;
  if (!hasKeyframe(c.from_id) || !hasKeyframe(c.to_id))
    throw Error(name + " names a keyframe the pose graph does not know (" +
                std::to_string(hasKeyframe(c.from_id) ? c.to_id : c.from_id) + "); dropped");
  if (c.from_id == c.to_id) throw Error(name + " links a keyframe to itself; dropped");
  if (!isValidPose(c.relative, 1e-6)) throw Error(name + " has an invalid relative pose; dropped");
  Constraint checked = c;
  checked.information = checkedInformation(c, name);
  const bool moved = culled_.count(c.from_id) || culled_.count(c.to_id);
  if (moved) {
    checked = onKeptKeyframes(checked);
    compact_ = true;  // it may join two keyframes that have an edge already
    if (checked.from_id == checked.to_id) {
      ++edges_dropped_by_culling_;
      spdlog::debug("{} joins two keyframes culled onto one; dropped", name);
      return;
    }
  }
  insertEdge(checked, origin, name, moved);
}

void PoseGraph::insertEdge(const Constraint& c, const std::string& origin, const std::string& name, bool moved) {
  const size_t index = edges_.size();
  edges_.push_back(makeEdge(c, origin, moved));
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
  return params_.solver == Solver::Ceres ? solveCeres(final, report, first_round)
                                         : solveBlockCholesky(final, report, first_round);
}

int PoseGraph::solveCeres(bool final, OptimiseReport& report, bool first_round) {
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
    auto* cost = new detail::RelativePoseCost(*e.z, e.sqrt_information);
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

namespace {

// Robust loss rho(s) of a squared whitened residual s and its slope, as
// Ceres' CauchyLoss / HuberLoss with scale a define them.
struct Robust {
  double rho, slope;
};
Robust robust(RobustLoss loss, double a, double s) {
  const double a2 = a * a;
  switch (loss) {
    case RobustLoss::Cauchy: return {a2 * std::log1p(s / a2), 1.0 / (1.0 + s / a2)};
    case RobustLoss::Huber:
      if (s <= a2) return {s, 1.0};
      return {2.0 * a * std::sqrt(s) - a2, a / std::sqrt(s)};
    case RobustLoss::None: break;
  }
  return {s, 1.0};
}

// Ceres' EigenQuaternionManifold retraction with phi = 2 delta: q' = Exp(phi) q.
void retract(const double* x, const double* step, double* out) {
  for (int i = 0; i < 3; ++i) out[i] = x[i] + step[i];
  const Eigen::Vector3d phi(step[3], step[4], step[5]);
  const double angle = phi.norm();
  Eigen::Quaterniond dq = Eigen::Quaterniond::Identity();
  if (angle > 0) dq = Eigen::Quaterniond(Eigen::AngleAxisd(angle, phi / angle));
  const Eigen::Quaterniond q = (dq * Eigen::Quaterniond(x + 3)).normalized();
  for (int i = 0; i < 4; ++i) out[3 + i] = q.coeffs()[i];
}

// Levenberg-Marquardt damping of solveBlockCholesky: lambda scales diag(H).
// Starting small makes the first steps Gauss-Newton steps (a pose graph
// from chained odometry is well within their basin); beyond the maximum a
// step is too short to matter and the solve ends.
constexpr double kInitialDamping = 1e-6;
constexpr double kMinDamping = 1e-9;
constexpr double kMaxDamping = 1e6;

// One kept edge between attached keyframes as the block-Cholesky solve sees
// it: the parameter blocks of its keyframes, their variable indices (-1 for
// the fixed anchor) and its off-diagonal block in the factor (-1 without one).
struct Term {
  const detail::RelativeMeasurement* z;
  const Matrix6d* sqrt_information;
  bool loop;
  const double* a;
  const double* b;
  int ia, ib, pair;
};

// When a solve stops: after max_iterations, at a relative decrease of the cost
// below tolerance, or (unless final) once max_solver_time_s have passed since start.
struct StopRule {
  bool final;
  int max_iterations;
  double tolerance;
  double max_solver_time_s;
  std::chrono::steady_clock::time_point start;
};

// 0.5 * sum of the robustified squared whitened residuals: at the current
// poses, or with each variable at moved[variable] where moved is given.
double totalCost(const std::vector<Term>& terms, const PoseGraphParams& params,
                 const std::vector<const double*>* moved) {
  double total = 0.0;
  Vector6d e;
  for (const Term& t : terms) {
    const double* a = t.ia >= 0 && moved ? (*moved)[static_cast<size_t>(t.ia)] : t.a;
    const double* b = t.ib >= 0 && moved ? (*moved)[static_cast<size_t>(t.ib)] : t.b;
    detail::relativeErrorAndJacobians(a, b, *t.z, e, nullptr, nullptr);
    // U is stored with its zeros: a plain fixed-size product is faster than a triangular view.
    const Vector6d r = *t.sqrt_information * e;
    const double s = r.squaredNorm();
    total += t.loop ? robust(params.loop_loss, params.loop_loss_scale, s).rho : s;
  }
  return 0.5 * total;
}

// Normal equations J^T W J (into chol) and gradient J^T W r at the current
// poses, with the robust loss as iteratively reweighted least squares.
void linearise(const std::vector<Term>& terms, const PoseGraphParams& params, detail::BlockCholesky& chol,
               Eigen::VectorXd& gradient) {
  chol.setZero();
  gradient.setZero();
  auto& diag = chol.diagonal();
  auto& off = chol.offDiagonal();
  Vector6d e;
  Matrix6d ja, jb;
  for (const Term& t : terms) {
    detail::relativeErrorAndJacobians(t.a, t.b, *t.z, e, &ja, &jb);
    const Matrix6d& u = *t.sqrt_information;
    const Vector6d r = u * e;
    const double w = t.loop ? robust(params.loop_loss, params.loop_loss_scale, r.squaredNorm()).slope : 1.0;
    Matrix6d wa, wb;
    wa.noalias() = u * ja;
    wb.noalias() = u * jb;
    if (t.ia >= 0) {
      diag[static_cast<size_t>(t.ia)].noalias() += w * wa.transpose() * wa;
      gradient.segment<6>(6 * t.ia).noalias() += w * wa.transpose() * r;
    }
    if (t.ib >= 0) {
      diag[static_cast<size_t>(t.ib)].noalias() += w * wb.transpose() * wb;
      gradient.segment<6>(6 * t.ib).noalias() += w * wb.transpose() * r;
    }
    if (t.pair >= 0) {
      if (chol.pairRows()[static_cast<size_t>(t.pair)].first == t.ia)
        off[static_cast<size_t>(t.pair)].noalias() += w * wa.transpose() * wb;
      else
        off[static_cast<size_t>(t.pair)].noalias() += w * wb.transpose() * wa;
    }
  }
}

// Levenberg-Marquardt on H + lambda diag(H): close to Gauss-Newton while
// steps succeed, a shorter gradient-like step after one that failed. Moves
// the variables' parameter blocks (vars, those the terms point to) in place;
// `current` is their cost on entry and on return. Returns the iterations.
int levenbergMarquardt(const std::vector<Term>& terms, const std::vector<double*>& vars, detail::BlockCholesky& chol,
                       const PoseGraphParams& params, const StopRule& stop, double& current) {
  const int n = static_cast<int>(vars.size());
  Eigen::VectorXd gradient(6 * n);
  std::vector<double> candidate(7 * static_cast<size_t>(n));
  std::vector<const double*> moved(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) moved[static_cast<size_t>(i)] = candidate.data() + 7 * i;
  double lambda = kInitialDamping;
  int iterations = 0;
  bool relinearise = true;
  Eigen::VectorXd step;
  while (iterations < stop.max_iterations) {
    if (!stop.final && std::chrono::duration<double>(std::chrono::steady_clock::now() - stop.start).count() >
                           stop.max_solver_time_s)
      break;
    if (relinearise) linearise(terms, params, chol, gradient);
    relinearise = false;
    ++iterations;
    if (!chol.factorize(lambda)) {
      lambda *= 10.0;
      continue;
    }
    step = -gradient;
    chol.solve(step);
    for (int i = 0; i < n; ++i) retract(vars[static_cast<size_t>(i)], step.data() + 6 * i, candidate.data() + 7 * i);
    const double next = totalCost(terms, params, &moved);
    if (!(next < current)) {
      lambda = std::min(lambda * 10.0, kMaxDamping);
      if (lambda >= kMaxDamping) break;  // no step along the gradient lowers the cost: converged
      continue;
    }
    for (int i = 0; i < n; ++i) std::copy_n(candidate.data() + 7 * i, 7, vars[static_cast<size_t>(i)]);
    const double decrease = (current - next) / current;
    current = next;
    lambda = std::max(lambda / 10.0, kMinDamping);
    relinearise = true;
    if (decrease < stop.tolerance) break;
  }
  return iterations;
}

}  // namespace

int PoseGraph::solveBlockCholesky(bool final, OptimiseReport& report, bool first_round) {
  const StopRule stop{final, final ? params_.final_max_iterations : params_.max_iterations,
                      final ? params_.final_function_tolerance : params_.function_tolerance,
                      params_.max_solver_time_s, std::chrono::steady_clock::now()};
  // Variables: the attached keyframes but the anchor, ascending id.
  std::vector<double*> vars;
  std::map<int64_t, int> index;
  for (auto& [id, n] : nodes_) {
    if (!n.attached || (anchor_ && id == *anchor_)) continue;
    index[id] = static_cast<int>(vars.size());
    vars.push_back(n.x);
  }
  std::vector<Term> terms;
  std::vector<std::pair<int, int>> pairs;
  std::set<int64_t> used;
  for (const Edge& e : edges_) {
    if (!e.kept) continue;
    const Node& a = nodes_.at(e.c.from_id);
    const Node& b = nodes_.at(e.c.to_id);
    if (!a.attached || !b.attached) continue;
    const auto ia = index.find(e.c.from_id), ib = index.find(e.c.to_id);
    Term t{e.z.get(), &e.sqrt_information, e.c.kind == EdgeKind::Loop, a.x, b.x,
           ia == index.end() ? -1 : ia->second, ib == index.end() ? -1 : ib->second, -1};
    if (t.ia >= 0 && t.ib >= 0) pairs.emplace_back(t.ia, t.ib);
    terms.push_back(t);
    used.insert(e.c.from_id);
    used.insert(e.c.to_id);
  }
  report.edges_used = static_cast<int>(terms.size());
  report.keyframes_optimised = static_cast<int>(used.size());
  if (terms.empty()) return 0;
  detail::BlockCholesky& chol = analysedCholesky(static_cast<int>(vars.size()), pairs);
  for (Term& t : terms) {
    if (t.ia >= 0 && t.ib >= 0) t.pair = chol.pairIndex(t.ia, t.ib);
  }
  double current = totalCost(terms, params_, nullptr);
  if (first_round) report.initial_cost = current;
  const int iterations = levenbergMarquardt(terms, vars, chol, params_, stop, current);
  report.final_cost = current;
  return iterations;
}

detail::BlockCholesky& PoseGraph::analysedCholesky(int n, const std::vector<std::pair<int, int>>& pairs) {
  // The symbolic analysis is redone only when the pattern changed (a new
  // keyframe or edge, a removed outlier).
  if (!cholesky_ || cholesky_pairs_ != pairs || cholesky_->size() != n) {
    if (!cholesky_) cholesky_ = std::make_unique<detail::BlockCholesky>();
    cholesky_->analyse(n, pairs);
    cholesky_pairs_ = pairs;
  }
  return *cholesky_;
}

OptimiseReport PoseGraph::optimise(bool final) {
  const auto start = std::chrono::steady_clock::now();
  const double cpu_start = threadCpuMs();
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
        // The frontend's outliers are routine; an external constraint the graph contradicts is news to its sender.
        spdlog::log(e.origin.empty() ? spdlog::level::debug : spdlog::level::warn,
                    "removed outlier {} (chi2 {:.1f} > {:.1f}): it contradicts the rest of the graph", nameOf(e), chi2,
                    params_.loop_outlier_chi2);
      }
    }
    if (removed == 0) break;
    report.loop_edges_removed += removed;
    loop_edges_removed_ += static_cast<size_t>(removed);
    compact_ = true;
    recomputeAttachment();
  }
  cullSettledKeyframes();
  if (compact_) compactEdges();
  report.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  report.cpu_ms = threadCpuMs() - cpu_start;
  return report;
}

std::optional<Pose> PoseGraph::pose(int64_t id) const {
  if (!hasKeyframe(id)) return std::nullopt;
  const auto [kept, in_kept] = resolve(id);
  return Pose(poseOf(nodes_.at(kept)) * in_kept);
}

std::vector<std::pair<int64_t, Pose>> PoseGraph::poses() const {
  std::vector<std::pair<int64_t, Pose>> out;
  out.reserve(numKeyframes());
  for (const auto& [id, n] : nodes_) out.emplace_back(id, poseOf(n));
  for (const auto& [id, c] : culled_) out.emplace_back(id, *pose(id));
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  return out;
}

bool PoseGraph::isAttached(int64_t id) const {
  if (!hasKeyframe(id)) return false;
  return nodes_.at(resolve(id).first).attached;
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

std::vector<Constraint> PoseGraph::constraints() const {
  std::vector<Constraint> out;
  for (const Edge& e : edges_) {
    if (e.kept) out.push_back(e.c);
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
