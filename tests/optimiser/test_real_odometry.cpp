// The pose graph on the tracker's real odometry (7-Scenes loop, 1 000
// frames): loop edges taken from the ground truth, some of them made wrong.
// This checks that information_scale calibrates the tracker's information so
// that correct loops survive the outlier test and wrong ones do not.
#include <gtest/gtest.h>

#include <cstdio>
#include <map>
#include <random>

#include "rekon/common/config.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/se3.hpp"
#include "rekon/eval/trajectory_eval.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/optimiser/synthetic_graph.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/tracker.hpp"
#include "test_support.hpp"

namespace rekon::optimiser {
namespace {

// Loop edges: for each new keyframe, up to 2 earlier keyframes (more than 5
// keyframes back) whose true camera centres lie within 0.5 m; the true
// relative pose with 1 cm / 5 mrad noise per axis, and the information of
// the new keyframe's odometry edge (what a dense alignment would claim).
// Every 10th is made wrong by 30 cm, like a false place recognition.
constexpr double kLoopRadiusM = 0.5;
constexpr int kMinKeyframeGap = 5;
constexpr int kLoopsPerKeyframe = 2;
constexpr double kLoopNoiseTranslationM = 0.01;
constexpr double kLoopNoiseRotationRad = 0.005;
constexpr double kWrongOffsetM = 0.3;

TEST(PoseGraphOnRealOdometry, GroundTruthLoopsCutTheAteBelow70PercentAndWrongOnesAreRemoved) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  TumDataset dataset(data);
  ASSERT_TRUE(dataset.hasGroundTruth());
  tracker::Tracker tracker(tracker::trackerParamsFromConfig(Config::load()));
  const double scale = OptimiserServiceParams::kDefaultInformationScale;
  PoseGraph graph;
  std::map<int64_t, Pose> keyframe_truth;
  std::vector<TrackedFrame> frames;
  Trajectory odometry;
  std::mt19937 rng(1);
  std::normal_distribution<double> normal(0.0, 1.0);
  int correct_loops = 0, wrong_loops = 0;
  for (size_t i = 0; i < dataset.size(); ++i) {
    const tracker::TrackResult r = tracker.track(dataset.load(i), dataset.intrinsics());
    odometry.push_back({r.timestamp, r.pose_world});
    frames.push_back({static_cast<int64_t>(i), r.timestamp, r.keyframe_id, r.pose_in_keyframe});
    if (r.new_keyframe) {
      graph.addKeyframe(r.keyframe_id, r.keyframe_pose_world);
      const int gt = nearestInTime(dataset.groundTruth(), r.timestamp, 0.02);
      ASSERT_GE(gt, 0);
      keyframe_truth[r.keyframe_id] = dataset.groundTruth()[static_cast<size_t>(gt)].pose;
    }
    if (!r.odometry) continue;
    Constraint odo;
    odo.from_id = r.odometry->from_id;
    odo.to_id = r.odometry->to_id;
    odo.relative = r.odometry->relative;
    odo.information = scale * r.odometry->information;
    graph.addConstraint(odo);
    const Pose& to_truth = keyframe_truth.at(odo.to_id);
    int added = 0;
    for (const auto& [id, from_truth] : keyframe_truth) {
      if (id + kMinKeyframeGap >= odo.to_id || added == kLoopsPerKeyframe) continue;
      if ((from_truth.translation() - to_truth.translation()).norm() > kLoopRadiusM) continue;
      Vector6d xi;
      for (int k = 0; k < 3; ++k) xi[k] = kLoopNoiseTranslationM * normal(rng);
      for (int k = 3; k < 6; ++k) xi[k] = kLoopNoiseRotationRad * normal(rng);
      Constraint loop;
      loop.kind = EdgeKind::Loop;
      loop.from_id = id;
      loop.to_id = odo.to_id;
      loop.relative = orthonormalised(from_truth.inverse() * to_truth * expSe3(xi));
      loop.information = odo.information;
      if ((correct_loops + wrong_loops) % 10 == 5) {
        loop.relative.translation() += Eigen::Vector3d(kWrongOffsetM, 0.0, 0.0);
        ++wrong_loops;
      } else {
        ++correct_loops;
      }
      graph.addConstraint(loop);
      ++added;
    }
    graph.optimise(false);  // as the service does after each batch
  }
  graph.optimise(true);
  ASSERT_GT(correct_loops, 50) << "the sequence revisits its places many times";

  // No wrong loop edge survives; at most 5 % of the correct ones go.
  int kept_correct = 0;
  for (const Constraint& c : graph.loopEdges()) {
    const Pose truth = keyframe_truth.at(c.from_id).inverse() * keyframe_truth.at(c.to_id);
    const double error = (c.relative.translation() - truth.translation()).norm();
    EXPECT_LT(error, kWrongOffsetM / 2) << "wrong loop edge " << c.from_id << " -> " << c.to_id << " kept";
    kept_correct += error < kWrongOffsetM / 2;
  }
  EXPECT_GE(kept_correct, correct_loops * 95 / 100) << "of " << correct_loops << " correct loop edges";

  size_t missing = 0;
  const Trajectory optimised = frameTrajectory(graph, frames, &missing);
  EXPECT_EQ(missing, 0u);
  const double ate_odometry = eval::evaluateTrajectory(dataset.groundTruth(), odometry).ate_rmse_m;
  const double ate_optimised = eval::evaluateTrajectory(dataset.groundTruth(), optimised).ate_rmse_m;
  std::printf("%zu keyframes, %d correct loop edges (%d kept), %d wrong; ATE odometry %.4f m, optimised %.4f m\n",
              graph.numKeyframes(), correct_loops, kept_correct, wrong_loops, ate_odometry, ate_optimised);
  // Measured 0.055 m -> 0.025 m; the goal for real loop closures is 0.7x.
  EXPECT_LT(ate_optimised, 0.7 * ate_odometry) << "odometry " << ate_odometry << " m, optimised " << ate_optimised << " m";
}

}  // namespace
}  // namespace rekon::optimiser
