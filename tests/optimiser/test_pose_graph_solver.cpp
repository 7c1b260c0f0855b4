// The pieces of the pose-graph solve: the closed-form Jacobians of the
// relative-pose residual, the 6x6-block sparse Cholesky, and the block
// Cholesky solver against Ceres (the reference) on the same graphs.
#include <ceres/manifold.h>
#include <ceres/product_manifold.h>
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <random>

#include "block_cholesky.hpp"
#include "rekon/common/se3.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/optimiser/synthetic_graph.hpp"
#include "relative_pose_cost.hpp"

namespace rekon::optimiser {
namespace {

using detail::Block6;

// A pose block (tx, ty, tz, qx, qy, qz, qw) well away from identity.
std::array<double, 7> randomPoseBlock(std::mt19937_64& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::Quaterniond q(normal(rng), normal(rng), normal(rng), normal(rng));
  q.normalize();
  return {normal(rng), normal(rng), normal(rng), q.x(), q.y(), q.z(), q.w()};
}

Pose poseOfBlock(const std::array<double, 7>& x) {
  return poseFromQuatTrans(Eigen::Quaterniond(x[6], x[3], x[4], x[5]), Eigen::Vector3d(x[0], x[1], x[2]));
}

// t + dt, Exp(phi) R: the perturbation the closed-form Jacobians are for.
std::array<double, 7> perturb(const std::array<double, 7>& x, const Vector6d& step) {
  Pose p = poseOfBlock(x);
  p.translation() += step.head<3>();
  const Eigen::Vector3d phi = step.tail<3>();
  if (phi.norm() > 0) p.linear() = Eigen::AngleAxisd(phi.norm(), phi.normalized()).toRotationMatrix() * p.linear();
  const Eigen::Quaterniond q(p.linear());
  return {p.translation().x(), p.translation().y(), p.translation().z(), q.x(), q.y(), q.z(), q.w()};
}

TEST(RelativePoseJacobians, ClosedFormMatchesCentralDifferences) {
  std::mt19937_64 rng(11);
  for (int trial = 0; trial < 20; ++trial) {
    const auto a = randomPoseBlock(rng), b = randomPoseBlock(rng);
    // A measurement near the true relative pose (a converging graph) on odd
    // trials, far from it on even ones (the error's quaternion then has w < 0
    // about half the time: the sign flip must be differentiated too).
    Pose z = poseOfBlock(a).inverse() * poseOfBlock(b);
    if (trial % 2 == 0) z = z * poseOfBlock(randomPoseBlock(rng));
    const detail::RelativeMeasurement m(Eigen::Quaterniond(z.linear()).conjugate(), z.translation());
    Vector6d e;
    Matrix6d ja, jb;
    detail::relativeErrorAndJacobians(a.data(), b.data(), m, e, &ja, &jb);
    EXPECT_NEAR((e - relativePoseResidual(poseOfBlock(a), poseOfBlock(b), z)).norm(), 0.0, 1e-12);
    const double h = 1e-6;
    for (int k = 0; k < 6; ++k) {
      Vector6d step = Vector6d::Zero();
      step[k] = h;
      Vector6d plus, minus;
      detail::relativeErrorAndJacobians(perturb(a, step).data(), b.data(), m, plus, nullptr, nullptr);
      detail::relativeErrorAndJacobians(perturb(a, -step).data(), b.data(), m, minus, nullptr, nullptr);
      // Central differences are exact to O(h^2) ~ 1e-12 times the third derivative; 1e-7 leaves room for rounding.
      EXPECT_NEAR((ja.col(k) - (plus - minus) / (2 * h)).norm(), 0.0, 1e-7) << "trial " << trial << " a column " << k;
      detail::relativeErrorAndJacobians(a.data(), perturb(b, step).data(), m, plus, nullptr, nullptr);
      detail::relativeErrorAndJacobians(a.data(), perturb(b, -step).data(), m, minus, nullptr, nullptr);
      EXPECT_NEAR((jb.col(k) - (plus - minus) / (2 * h)).norm(), 0.0, 1e-7) << "trial " << trial << " b column " << k;
    }
  }
}

TEST(RelativePoseJacobians, CeresCostTimesThePlusJacobianIsTheManifoldDerivative) {
  // What Ceres uses is J_ambient * PlusJacobian: it must equal the derivative
  // of the whitened residual along the manifold's own Plus.
  std::mt19937_64 rng(5);
  const ceres::ProductManifold<ceres::EuclideanManifold<3>, ceres::EigenQuaternionManifold> manifold;
  for (int trial = 0; trial < 10; ++trial) {
    const auto a = randomPoseBlock(rng), b = randomPoseBlock(rng);
    const Pose z = poseOfBlock(a).inverse() * poseOfBlock(b) * poseOfBlock(randomPoseBlock(rng));
    Matrix6d u = isotropicInformation(0.01, 0.02).llt().matrixU();
    u(0, 4) = 3.0;  // upper triangular, not diagonal
    const detail::RelativePoseCost cost(
        detail::RelativeMeasurement(Eigen::Quaterniond(z.linear()).conjugate(), z.translation()), u);
    const double* params[2] = {a.data(), b.data()};
    Eigen::Matrix<double, 6, 7, Eigen::RowMajor> ja, jb;
    double* jacobians[2] = {ja.data(), jb.data()};
    Vector6d r;
    ASSERT_TRUE(cost.Evaluate(params, r.data(), jacobians));
    for (int block = 0; block < 2; ++block) {
      const auto& x = block == 0 ? a : b;
      Eigen::Matrix<double, 7, 6, Eigen::RowMajor> plus_jacobian;
      ASSERT_TRUE(manifold.PlusJacobian(x.data(), plus_jacobian.data()));
      const Matrix6d tangent = (block == 0 ? ja : jb) * plus_jacobian;
      const double h = 1e-6;
      for (int k = 0; k < 6; ++k) {
        double delta[6] = {0, 0, 0, 0, 0, 0};
        std::array<double, 7> xp{}, xm{};
        delta[k] = h;
        manifold.Plus(x.data(), delta, xp.data());
        delta[k] = -h;
        manifold.Plus(x.data(), delta, xm.data());
        const double* pp[2] = {block == 0 ? xp.data() : a.data(), block == 0 ? b.data() : xp.data()};
        const double* pm[2] = {block == 0 ? xm.data() : a.data(), block == 0 ? b.data() : xm.data()};
        Vector6d rp, rm;
        cost.Evaluate(pp, rp.data(), nullptr);
        cost.Evaluate(pm, rm.data(), nullptr);
        // The residual scale is ~1e2 (sigma 1 cm): 1e-5 relative to it.
        EXPECT_NEAR((tangent.col(k) - (rp - rm) / (2 * h)).norm(), 0.0, 1e-3)
            << "trial " << trial << " block " << block << " column " << k;
      }
    }
  }
}

// A random symmetric positive-definite block matrix on the given pattern.
struct BlockSystem {
  detail::BlockCholesky chol;
  Eigen::MatrixXd dense;
};
BlockSystem randomSystem(int n, const std::vector<std::pair<int, int>>& pairs, std::mt19937_64& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  BlockSystem s;
  s.chol.analyse(n, pairs);
  s.dense = Eigen::MatrixXd::Zero(6 * n, 6 * n);
  s.chol.setZero();
  // Sum of J^T J of random 6x12 "edges": positive semi-definite, plus a
  // diagonal prior so that every block row is definite.
  for (const auto& [i, j] : pairs) {
    Eigen::Matrix<double, 6, 12> jac = Eigen::Matrix<double, 6, 12>::NullaryExpr([&] { return normal(rng); });
    const Eigen::Matrix<double, 12, 12> h = jac.transpose() * jac;
    s.chol.diagonal()[static_cast<size_t>(i)] += h.topLeftCorner<6, 6>();
    s.chol.diagonal()[static_cast<size_t>(j)] += h.bottomRightCorner<6, 6>();
    const int k = s.chol.pairIndex(i, j);
    if (s.chol.pairRows()[static_cast<size_t>(k)].first == i)
      s.chol.offDiagonal()[static_cast<size_t>(k)] += h.topRightCorner<6, 6>();
    else
      s.chol.offDiagonal()[static_cast<size_t>(k)] += h.bottomLeftCorner<6, 6>();
    s.dense.block<6, 6>(6 * i, 6 * i) += h.topLeftCorner<6, 6>();
    s.dense.block<6, 6>(6 * j, 6 * j) += h.bottomRightCorner<6, 6>();
    s.dense.block<6, 6>(6 * i, 6 * j) += h.topRightCorner<6, 6>();
    s.dense.block<6, 6>(6 * j, 6 * i) += h.bottomLeftCorner<6, 6>();
  }
  for (int i = 0; i < n; ++i) {
    s.chol.diagonal()[static_cast<size_t>(i)].diagonal().array() += 0.1;
    s.dense.block<6, 6>(6 * i, 6 * i).diagonal().array() += 0.1;
  }
  return s;
}

TEST(BlockCholesky, SolvesLikeADenseCholeskyOnGraphPatterns) {
  std::mt19937_64 rng(3);
  const int n = 60;
  std::vector<std::vector<std::pair<int, int>>> patterns(3);
  for (int i = 0; i + 1 < n; ++i) patterns[0].emplace_back(i, i + 1);  // a chain: no fill
  patterns[1] = patterns[0];
  patterns[1].emplace_back(n - 1, 0);  // a ring
  patterns[1].emplace_back(0, n - 1);  // the same pair again, reversed: summed
  std::uniform_int_distribution<int> pick(0, n - 1);
  patterns[2] = patterns[0];
  for (int k = 0; k < 150; ++k) {  // loops everywhere: heavy fill
    const int i = pick(rng), j = pick(rng);
    if (i != j) patterns[2].emplace_back(j, i);
  }
  for (size_t t = 0; t < patterns.size(); ++t) {
    BlockSystem s = randomSystem(n, patterns[t], rng);
    ASSERT_TRUE(s.chol.factorize());
    const Eigen::VectorXd b = Eigen::VectorXd::NullaryExpr(6 * n, [&] { return std::normal_distribution<double>()(rng); });
    Eigen::VectorXd x = b;
    s.chol.solve(x);
    const Eigen::VectorXd expected = s.dense.llt().solve(b);
    EXPECT_LT((x - expected).norm(), 1e-8 * expected.norm()) << "pattern " << t;
  }
}

TEST(BlockCholesky, DampingScalesTheDiagonal) {
  std::mt19937_64 rng(4);
  BlockSystem s = randomSystem(10, {{0, 1}, {1, 2}, {2, 9}, {5, 6}}, rng);
  ASSERT_TRUE(s.chol.factorize(0.5));
  const Eigen::VectorXd b = Eigen::VectorXd::Ones(60);
  Eigen::VectorXd x = b;
  s.chol.solve(x);
  Eigen::MatrixXd damped = s.dense;
  damped.diagonal() *= 1.5;  // (H + 0.5 diag(H))
  EXPECT_LT((x - damped.llt().solve(b)).norm(), 1e-8 * x.norm());
}

TEST(BlockCholesky, AnIndefiniteMatrixIsReportedNotFactorised) {
  std::mt19937_64 rng(6);
  BlockSystem s = randomSystem(4, {{0, 1}, {2, 3}}, rng);
  s.chol.diagonal()[2](1, 1) = -5.0;
  EXPECT_FALSE(s.chol.factorize());
}

// Five laps of 200 keyframes with 1 500 loop edges, ten of them made wrong.
SyntheticGraph multiLapGraph() {
  SyntheticGraphSpec spec;
  spec.keyframes = 1000;
  spec.laps = 5;
  spec.loop_edges = 1500;
  spec.seed = 9;
  SyntheticGraph g = makeSyntheticGraph(spec);
  for (size_t k = g.constraints.size() - 10; k < g.constraints.size(); ++k)
    g.constraints[k].relative = g.constraints[k].relative * expSe3((Vector6d() << 0.3, 0, 0, 0, 0.2, 0).finished());
  return g;
}

TEST(PoseGraphSolver, BlockCholeskyReachesTheSameOptimumAsCeres) {
  const SyntheticGraph g = multiLapGraph();
  std::vector<std::vector<std::pair<int64_t, Pose>>> results;
  std::vector<size_t> removed;
  for (const Solver solver : {Solver::Ceres, Solver::BlockCholesky}) {
    PoseGraphParams params;
    params.solver = solver;
    PoseGraph graph(params);
    for (size_t i = 0; i < g.initial.size(); ++i) graph.addKeyframe(static_cast<int64_t>(i), g.initial[i]);
    for (const Constraint& c : g.constraints) graph.addConstraint(c);
    graph.optimise(true);
    results.push_back(graph.poses());
    removed.push_back(graph.loopEdgesRemoved());
  }
  EXPECT_EQ(removed[0], removed[1]);
  EXPECT_GE(removed[1], 10u) << "the ten wrong loop edges";
  double worst = 0.0;
  for (size_t i = 0; i < results[0].size(); ++i)
    worst = std::max(worst, (results[0][i].second.translation() - results[1][i].second.translation()).norm());
  // Both stop at a relative cost decrease below 1e-6: the poses agree far
  // below the 5 mm noise of an edge.
  EXPECT_LT(worst, 1e-4);
  EXPECT_LT(maxTranslationError(g.truth, results[1]), 0.05);
}

}  // namespace
}  // namespace rekon::optimiser
