// The pose graph: residual convention, loop closure on a synthetic graph with
// known poses, outlier loop edges, keyframes not yet linked, malformed input.
#include <gtest/gtest.h>

#include <cmath>

#include "rekon/common/error.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/optimiser/synthetic_graph.hpp"

namespace rekon::optimiser {
namespace {

Pose rotationAbout(const Eigen::Vector3d& axis, double angle, const Eigen::Vector3d& t = Eigen::Vector3d::Zero()) {
  Pose p = Pose::Identity();
  p.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  p.translation() = t;
  return p;
}

// One lap of 60 keyframes around a 2 m circle (about 21 cm apart), odometry
// noise 3 mm and 0.3 mrad per edge and axis, closed by one exact loop edge
// from the last keyframe back to the first.
SyntheticGraphSpec oneLapSpec(uint64_t seed) {
  SyntheticGraphSpec spec;
  spec.keyframes = 60;
  spec.laps = 1;
  spec.sigma_translation_m = 0.003;
  spec.sigma_rotation_rad = 0.0003;
  spec.seed = seed;
  return spec;
}
SyntheticGraph oneLap(uint64_t seed = 3) { return makeSyntheticGraph(oneLapSpec(seed)); }

Constraint loopEdge(const SyntheticGraph& g, int from, int to, const Pose& error = Pose::Identity()) {
  Constraint c;
  c.kind = EdgeKind::Loop;
  c.from_id = from;
  c.to_id = to;
  c.relative = g.truth[from].inverse() * g.truth[to] * error;
  c.information = g.constraints.front().information;
  return c;
}

void addGraph(PoseGraph& graph, const SyntheticGraph& g) {
  for (size_t i = 0; i < g.initial.size(); ++i) graph.addKeyframe(static_cast<int64_t>(i), g.initial[i]);
  for (const Constraint& c : g.constraints) graph.addConstraint(c);
}

// The tolerance: after closing the loop, each keyframe's error is a Brownian
// bridge pinned at both ends (loopClosureErrorBound); 4 standard deviations
// per axis, plus 1 mm for the loop edge weighing only as much as one odometry
// edge. Odometry alone breaks it towards the end of the lap, where the bridge
// is pinned but the open chain has drifted most.
constexpr double kBridgeSigmas = 4.0;
constexpr double kSlackM = 0.001;

// Keyframes whose error exceeds the tolerance.
int keyframesOutsideTolerance(const SyntheticGraph& g, const SyntheticGraphSpec& spec,
                              const std::vector<std::pair<int64_t, Pose>>& poses) {
  int outside = 0;
  for (const auto& [id, pose] : poses) {
    const double err = (pose.translation() - g.truth[static_cast<size_t>(id)].translation()).norm();
    outside += err > loopClosureErrorBound(spec, static_cast<int>(id), kBridgeSigmas) + kSlackM;
  }
  return outside;
}

TEST(PoseGraph, ResidualIsTheRightPerturbationInTranslationThenRotationOrder) {
  // A measurement rotated 90 degrees about z, so that a left and a right
  // perturbation differ: the tracker's information is for the right one.
  const Pose measured = rotationAbout(Eigen::Vector3d::UnitZ(), M_PI / 2, Eigen::Vector3d(0.5, 0.0, 0.0));
  const Pose from = rotationAbout(Eigen::Vector3d(1, 1, 0), 0.3, Eigen::Vector3d(1.0, 2.0, 3.0));

  Pose shift = Pose::Identity();
  shift.translation() = Eigen::Vector3d(0.01, -0.02, 0.03);
  const Vector6d r_t = relativePoseResidual(from, from * measured * shift, measured);
  // A pure translation: exp is exact, so the residual is exactly v.
  EXPECT_NEAR((r_t.head<3>() - Eigen::Vector3d(0.01, -0.02, 0.03)).norm(), 0.0, 1e-12);
  EXPECT_NEAR(r_t.tail<3>().norm(), 0.0, 1e-12);

  const Eigen::Vector3d w(0.01, 0.0, 0.02);
  const Vector6d r_w = relativePoseResidual(from, from * measured * rotationAbout(w, w.norm()), measured);
  // 2 sin(theta/2) against theta: differs by theta^3/24 = 5e-7 at 0.022 rad.
  EXPECT_NEAR(r_w.head<3>().norm(), 0.0, 1e-12);
  EXPECT_NEAR((r_w.tail<3>() - w).norm(), 0.0, 1e-6);
}

TEST(PoseGraph, OneCorrectLoopEdgeRecoversTheTruth) {
  for (uint64_t seed = 1; seed <= 5; ++seed) {
    const SyntheticGraph g = oneLap(seed);
    PoseGraph graph;
    addGraph(graph, g);
    ASSERT_GT(keyframesOutsideTolerance(g, oneLapSpec(seed), graph.poses()), 0)
        << "seed " << seed << ": the odometry alone must break the tolerance for the test to mean something";
    graph.addConstraint(loopEdge(g, 59, 0));
    const OptimiseReport report = graph.optimise(true);
    EXPECT_EQ(report.keyframes_optimised, 60);
    EXPECT_EQ(report.loop_edges_removed, 0);
    EXPECT_EQ(keyframesOutsideTolerance(g, oneLapSpec(seed), graph.poses()), 0) << "seed " << seed;
    // The loop's own end: the last keyframe sits within 1 cm of the truth.
    EXPECT_LT((graph.pose(59)->translation() - g.truth[59].translation()).norm(), 0.01) << "seed " << seed;
  }
}

TEST(PoseGraph, FirstKeyframeStaysWhereItWasAdded) {
  const SyntheticGraph g = oneLap();
  PoseGraph graph;
  addGraph(graph, g);
  graph.addConstraint(loopEdge(g, 59, 0));
  graph.optimise(true);
  ASSERT_EQ(graph.anchorId(), 0);
  EXPECT_TRUE(graph.pose(0)->isApprox(g.initial[0], 1e-12));
}

TEST(PoseGraph, WrongLoopEdgeIsRemovedAndTheResultStaysWithinTolerance) {
  const SyntheticGraph g = oneLap();
  PoseGraph graph;
  addGraph(graph, g);
  graph.addConstraint(loopEdge(g, 59, 0));
  // Claims keyframe 30 (across the circle, 4 m away) sits 1 m and 20 degrees
  // off its true pose relative to keyframe 5: a wrong place recognition.
  graph.addConstraint(loopEdge(g, 5, 30, rotationAbout(Eigen::Vector3d::UnitY(), 0.35, Eigen::Vector3d(1.0, 0.0, 0.0))));
  const OptimiseReport report = graph.optimise(true);
  EXPECT_EQ(report.loop_edges_removed, 1);
  EXPECT_EQ(graph.numLoopEdges(), 1u) << "the correct loop edge is kept";
  EXPECT_EQ(keyframesOutsideTolerance(g, oneLapSpec(3), graph.poses()), 0);
}

TEST(PoseGraph, WithoutRobustLossOrRemovalTheWrongLoopEdgeWouldBreakTheResult) {
  // The control for the test above: the same graph with plain least squares
  // and no outlier removal ends far outside the tolerance.
  const SyntheticGraph g = oneLap();
  PoseGraphParams params;
  params.loop_loss = RobustLoss::None;
  params.outlier_rounds = 0;
  PoseGraph graph(params);
  addGraph(graph, g);
  graph.addConstraint(loopEdge(g, 59, 0));
  graph.addConstraint(loopEdge(g, 5, 30, rotationAbout(Eigen::Vector3d::UnitY(), 0.35, Eigen::Vector3d(1.0, 0.0, 0.0))));
  graph.optimise(true);
  EXPECT_GT(keyframesOutsideTolerance(g, oneLapSpec(3), graph.poses()), 10);
}

TEST(PoseGraph, HuberLossAlsoRejectsTheWrongLoopEdge) {
  const SyntheticGraph g = oneLap();
  PoseGraphParams params;
  params.loop_loss = RobustLoss::Huber;
  PoseGraph graph(params);
  addGraph(graph, g);
  graph.addConstraint(loopEdge(g, 59, 0));
  graph.addConstraint(loopEdge(g, 5, 30, rotationAbout(Eigen::Vector3d::UnitY(), 0.35, Eigen::Vector3d(1.0, 0.0, 0.0))));
  graph.optimise(true);
  EXPECT_EQ(graph.loopEdgesRemoved(), 1u);
  EXPECT_EQ(keyframesOutsideTolerance(g, oneLapSpec(3), graph.poses()), 0);
}

TEST(PoseGraph, ReoptimisingAConvergedGraphIsWarmStarted) {
  const SyntheticGraph g = oneLap();
  PoseGraph graph;
  addGraph(graph, g);
  graph.addConstraint(loopEdge(g, 59, 0));
  const OptimiseReport first = graph.optimise(true);
  const OptimiseReport again = graph.optimise(false);
  // Starting at the optimum: the cost it starts from is the cost the first
  // run ended with (nothing is reset to the tracker's poses), and it stays there.
  EXPECT_NEAR(again.initial_cost, first.final_cost, 1e-9 * first.final_cost);
  EXPECT_LE(again.final_cost, again.initial_cost);
  EXPECT_LT(first.final_cost, first.initial_cost);
}

TEST(PoseGraph, KeyframeWithoutEdgesKeepsTheTrackersPoseAndIsMovedRigidlyWhenLinked) {
  const SyntheticGraph g = oneLap();
  PoseGraph graph;
  for (int i = 0; i < 10; ++i) graph.addKeyframe(i, g.initial[i]);
  for (int i = 0; i < 9; ++i) graph.addConstraint(g.constraints[i]);
  // After a tracking reset: keyframes 20 and 21 with an odometry edge between
  // them but none to the rest, at poses 0.5 m off (the tracker's guess).
  const Pose offset = rotationAbout(Eigen::Vector3d::UnitY(), 0.2, Eigen::Vector3d(0.5, 0.0, 0.0));
  graph.addKeyframe(20, offset * g.truth[20]);
  graph.addKeyframe(21, offset * g.truth[21]);
  Constraint odo;
  odo.from_id = 20;
  odo.to_id = 21;
  odo.relative = g.truth[20].inverse() * g.truth[21];
  odo.information = g.constraints.front().information;
  graph.addConstraint(odo);
  graph.optimise(true);
  EXPECT_FALSE(graph.isAttached(20));
  EXPECT_TRUE(graph.pose(20)->isApprox(offset * g.truth[20], 1e-9)) << "an unlinked keyframe stays where the tracker put it";

  // A loop edge from keyframe 9 links both: 20 lands where the edge says,
  // 21 keeps its pose relative to 20.
  graph.addConstraint(loopEdge(g, 9, 20));
  EXPECT_TRUE(graph.isAttached(20));
  EXPECT_TRUE(graph.isAttached(21));
  EXPECT_TRUE(graph.pose(20)->isApprox(*graph.pose(9) * g.truth[9].inverse() * g.truth[20], 1e-9));
  EXPECT_TRUE((graph.pose(20)->inverse() * *graph.pose(21)).isApprox(g.truth[20].inverse() * g.truth[21], 1e-9));
  const OptimiseReport report = graph.optimise(true);
  EXPECT_EQ(report.keyframes_optimised, 12);
  EXPECT_EQ(report.loop_edges_removed, 0);
}

class MalformedConstraint : public ::testing::Test {
 protected:
  void SetUp() override {
    graph.addKeyframe(0, Pose::Identity());
    graph.addKeyframe(1, Pose::Identity());
    good.from_id = 0;
    good.to_id = 1;
    good.information = isotropicInformation(0.01, 0.01);
  }
  void expectDropped(const Constraint& c) {
    EXPECT_THROW(graph.addConstraint(c), Error);
    EXPECT_EQ(graph.numConstraints(), 0u);
    EXPECT_FALSE(graph.isAttached(1));
  }
  PoseGraph graph;
  Constraint good;
};

TEST_F(MalformedConstraint, UnknownKeyframeIdIsDropped) {
  Constraint c = good;
  c.to_id = 7;
  expectDropped(c);
}

TEST_F(MalformedConstraint, SelfEdgeIsDropped) {
  Constraint c = good;
  c.to_id = 0;
  expectDropped(c);
}

TEST_F(MalformedConstraint, NanInformationIsDropped) {
  Constraint c = good;
  c.information(2, 2) = std::nan("");
  expectDropped(c);
}

TEST_F(MalformedConstraint, SingularInformationIsDropped) {
  Constraint c = good;
  c.information.row(4).setZero();
  c.information.col(4).setZero();  // rotation about y unconstrained
  expectDropped(c);
}

TEST_F(MalformedConstraint, IndefiniteInformationIsDropped) {
  Constraint c = good;
  c.information(0, 0) = -1.0;
  expectDropped(c);
}

TEST_F(MalformedConstraint, AsymmetricInformationIsDropped) {
  Constraint c = good;
  c.information(0, 5) = 50.0;  // (5, 0) stays 0
  expectDropped(c);
}

TEST_F(MalformedConstraint, NonRotationRelativePoseIsDropped) {
  Constraint c = good;
  c.relative.linear()(0, 0) = 2.0;
  expectDropped(c);
}

TEST_F(MalformedConstraint, AValidEdgeIsAcceptedAfterwards) {
  // The graph is unharmed by what was dropped before.
  Constraint bad = good;
  bad.information(1, 1) = INFINITY;
  EXPECT_THROW(graph.addConstraint(bad), Error);
  graph.addConstraint(good);
  EXPECT_EQ(graph.numConstraints(), 1u);
  EXPECT_TRUE(graph.isAttached(1));
}

TEST(PoseGraph, DuplicateOrInvalidKeyframeIsDropped) {
  PoseGraph graph;
  graph.addKeyframe(0, Pose::Identity());
  EXPECT_THROW(graph.addKeyframe(0, Pose::Identity()), Error);
  Pose bad = Pose::Identity();
  bad.translation().x() = std::nan("");
  EXPECT_THROW(graph.addKeyframe(1, bad), Error);
  EXPECT_EQ(graph.numKeyframes(), 1u);
}

}  // namespace
}  // namespace rekon::optimiser
