// What arrives from the bus is validated, what leaves is complete, and
// consumers ignore graph updates older than the newest they have seen.
#include <gtest/gtest.h>

#include <cmath>

#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/optimiser/synthetic_graph.hpp"

namespace rekon::optimiser {
namespace {

Pose translated(double x, double y, double z) {
  Pose p = Pose::Identity();
  p.translation() = Eigen::Vector3d(x, y, z);
  return p;
}

rekon_msgs::constraint_t goodConstraintMsg() {
  rekon_msgs::constraint_t m{};
  m.kind = rekon_msgs::constraint_t::KIND_LOOP;
  m.from_id = 1;
  m.to_id = 2;
  m.relative = toMsg(translated(0.1, 0.0, 0.0));
  toArray(isotropicInformation(0.01, 0.01), m.information);
  return m;
}

TEST(GraphUpdateFilter, IgnoresVersionsOlderThanOrEqualToTheNewestSeen) {
  GraphUpdateFilter filter;
  EXPECT_FALSE(filter.seenAny());
  EXPECT_TRUE(filter.accept(1));
  EXPECT_TRUE(filter.accept(3));   // 2 was lost: fine, 3 carries everything
  EXPECT_FALSE(filter.accept(2));  // arrived late
  EXPECT_FALSE(filter.accept(3));  // the final update is sent three times
  EXPECT_TRUE(filter.accept(4));
  EXPECT_EQ(filter.newest(), 4);
}

TEST(GraphMessages, ConstraintMessageKeepsKindPoseAndInformation) {
  const Constraint c = constraintFromMsg(goodConstraintMsg());
  EXPECT_EQ(c.kind, EdgeKind::Loop);
  EXPECT_EQ(c.from_id, 1);
  EXPECT_EQ(c.to_id, 2);
  EXPECT_NEAR(c.relative.translation().x(), 0.1, 1e-15);
  EXPECT_EQ(c.information(0, 0), 1e4);  // 1 / 0.01^2
}

TEST(GraphMessages, InformationIsMultipliedByTheScale) {
  const Constraint c = constraintFromMsg(goodConstraintMsg(), 5e-5);
  EXPECT_NEAR(c.information(0, 0), 0.5, 1e-12);  // 1e4 * 5e-5
  EXPECT_EQ(c.information(0, 1), 0.0);
}

TEST(GraphMessages, ConstraintWithUnknownKindIsRejected) {
  rekon_msgs::constraint_t m = goodConstraintMsg();
  m.kind = 7;
  EXPECT_THROW(constraintFromMsg(m), Error);
}

TEST(GraphMessages, ConstraintWithInfiniteInformationIsRejected) {
  rekon_msgs::constraint_t m = goodConstraintMsg();
  m.information[14] = INFINITY;
  EXPECT_THROW(constraintFromMsg(m), Error);
}

TEST(GraphMessages, ConstraintWithNanOrNonUnitQuaternionIsRejected) {
  rekon_msgs::constraint_t m = goodConstraintMsg();
  m.relative.q[3] = std::nan("");
  EXPECT_THROW(constraintFromMsg(m), Error);
  m = goodConstraintMsg();
  m.relative.q[3] = 2.0;
  EXPECT_THROW(constraintFromMsg(m), Error);
}

TEST(GraphMessages, KeyframeWithNanPoseIsRejected) {
  rekon_msgs::keyframe_t m{};
  m.keyframe_id = 4;
  m.pose_world = toMsg(Pose::Identity());
  EXPECT_EQ(keyframeFromMsg(m).id, 4);
  m.pose_world.t[1] = std::nan("");
  EXPECT_THROW(keyframeFromMsg(m), Error);
}

TEST(GraphMessages, TrackedFrameWithInfinitePoseOrTimestampIsRejected) {
  rekon_msgs::tracked_frame_t m{};
  m.frame_id = 9;
  m.timestamp = 1.5;
  m.keyframe_id = 2;
  m.pose_in_keyframe = toMsg(translated(0, 0, 1));
  EXPECT_EQ(trackedFrameFromMsg(m).keyframe_id, 2);
  m.timestamp = INFINITY;
  EXPECT_THROW(trackedFrameFromMsg(m), Error);
  m.timestamp = 1.5;
  m.pose_in_keyframe.t[0] = -INFINITY;
  EXPECT_THROW(trackedFrameFromMsg(m), Error);
}

TEST(GraphMessages, GraphUpdateCarriesEveryKeyframeInAscendingOrder) {
  PoseGraph graph;
  graph.addKeyframe(5, translated(5, 0, 0));
  graph.addKeyframe(2, translated(2, 0, 0));
  graph.addKeyframe(9, translated(9, 0, 0));  // no edge: still part of the complete state
  const rekon_msgs::graph_update_t m = graphUpdateMsg(graph, 12, true);
  EXPECT_EQ(m.version, 12);
  EXPECT_TRUE(m.final_update);
  ASSERT_EQ(m.num_keyframes, 3);
  EXPECT_EQ(m.keyframe_ids, (std::vector<int64_t>{2, 5, 9}));
  EXPECT_EQ(m.poses[2].t[0], 9.0);
}

TEST(GraphMessages, TrajectoryIsKeyframePoseTimesPoseInKeyframeInFrameOrder) {
  PoseGraph graph;
  Pose kf = translated(1, 2, 3);
  kf.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  graph.addKeyframe(0, kf);
  std::vector<TrackedFrame> frames = {{11, 1.1, 0, translated(1, 0, 0)},
                                      {10, 1.0, 0, Pose::Identity()},
                                      {12, 1.2, 3, Pose::Identity()}};  // keyframe 3 never arrived
  size_t missing = 0;
  const Trajectory t = frameTrajectory(graph, frames, &missing);
  EXPECT_EQ(missing, 1u);
  ASSERT_EQ(t.size(), 2u);
  EXPECT_EQ(t[0].timestamp, 1.0);
  EXPECT_EQ(t[1].timestamp, 1.1);
  // x of the frame is y of the world after the 90 degree turn about z.
  EXPECT_NEAR((t[1].pose.translation() - Eigen::Vector3d(1, 3, 3)).norm(), 0.0, 1e-12);
}

TEST(OptimiserParams, DefaultConfigMatchesTheNamedDefaults) {
  const OptimiserServiceParams p = optimiserParamsFromConfig(Config::load());
  const PoseGraphParams d;
  EXPECT_EQ(p.graph.loop_loss, RobustLoss::Cauchy);
  EXPECT_EQ(p.graph.loop_loss_scale, d.loop_loss_scale);
  EXPECT_EQ(p.graph.loop_outlier_chi2, d.loop_outlier_chi2);
  EXPECT_EQ(p.graph.outlier_rounds, d.outlier_rounds);
  EXPECT_EQ(p.graph.max_iterations, d.max_iterations);
  EXPECT_EQ(p.graph.max_solver_time_s, d.max_solver_time_s);
  EXPECT_EQ(p.graph.final_max_iterations, d.final_max_iterations);
  EXPECT_EQ(p.graph.function_tolerance, d.function_tolerance);
  EXPECT_EQ(p.graph.final_function_tolerance, d.final_function_tolerance);
  EXPECT_EQ(p.information_scale, OptimiserServiceParams::kDefaultInformationScale);
  EXPECT_EQ(p.final_repeats, OptimiserServiceParams::kDefaultFinalRepeats);
  EXPECT_EQ(p.final_repeat_gap_ms, OptimiserServiceParams::kDefaultFinalRepeatGapMs);
  EXPECT_EQ(p.nice, 0);
}

TEST(OptimiserParams, InvalidValuesAreErrorsNamingTheKey) {
  try {
    optimiserParamsFromConfig(Config::load("", {"optimiser.loop_loss_scale=-1"}));
    FAIL() << "a negative loss scale must be rejected";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("optimiser.loop_loss_scale"), std::string::npos) << e.what();
  }
  EXPECT_THROW(optimiserParamsFromConfig(Config::load("", {"optimiser.loop_loss=tukey"})), Error);
  for (const char* nice : {"optimiser.nice=-1", "optimiser.nice=20"}) {
    try {
      optimiserParamsFromConfig(Config::load("", {nice}));
      FAIL() << nice << " must be rejected";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("optimiser.nice"), std::string::npos) << e.what();
    }
  }
  try {
    optimiserParamsFromConfig(Config::load("", {"optimiser.loop_neighbours_max=-1"}));
    FAIL() << "a negative cap must be rejected";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("optimiser.loop_neighbours_max"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace rekon::optimiser
