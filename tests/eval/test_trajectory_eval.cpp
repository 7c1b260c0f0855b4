// `evaluateTrajectory`: ATE after rigid alignment and RPE per second.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <numbers>

#include "rekon/common/error.hpp"
#include "rekon/eval/trajectory_eval.hpp"
#include "test_support.hpp"

namespace {

using rekon::Pose;
using rekon::Trajectory;

constexpr double kDeg = std::numbers::pi / 180.0;

// A curved 10 s walk at 30 Hz with turning and tilting, so alignment is well posed.
Trajectory walk() {
  Trajectory t;
  for (int i = 0; i < 300; ++i) {
    const double s = i / 30.0;
    Pose p = Pose::Identity();
    p.linear() = (Eigen::AngleAxisd(0.3 * s, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(0.1 * std::sin(s), Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    p.translation() = Eigen::Vector3d(std::cos(0.3 * s), std::sin(0.3 * s), 0.2 * std::sin(0.7 * s));
    t.push_back({s, p});
  }
  return t;
}

TEST(EvalTrajectory, ATrajectoryAgainstItselfHasNoError) {
  const auto e = rekon::eval::evaluateTrajectory(walk(), walk());
  EXPECT_EQ(e.matched, 300u);
  EXPECT_NEAR(e.ate_rmse_m, 0.0, 1e-12);
  EXPECT_NEAR(e.rpe_trans_m_per_s, 0.0, 1e-12);
  EXPECT_NEAR(e.rpe_rot_deg_per_s, 0.0, 1e-9);
}

TEST(EvalTrajectory, ARigidlyMovedCopyHasNoErrorAfterAlignment) {
  Pose motion = Pose::Identity();
  motion.linear() = Eigen::AngleAxisd(1.0, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  motion.translation() = Eigen::Vector3d(4, -5, 6);
  Trajectory moved = walk();
  for (auto& p : moved) p.pose = motion * p.pose;
  const auto e = rekon::eval::evaluateTrajectory(walk(), moved);
  EXPECT_NEAR(e.ate_rmse_m, 0.0, 1e-9);
  EXPECT_NEAR(e.rpe_trans_m_per_s, 0.0, 1e-9);  // relative motions do not change under a common motion
  EXPECT_NEAR(e.rpe_rot_deg_per_s, 0.0, 1e-6);
  EXPECT_TRUE(e.alignment.isApprox(motion.inverse(), 1e-9));
}

TEST(EvalTrajectory, OpposedOffsetsGiveTheirSizeAsAte) {
  // Each place on a curved walk is visited by two frames, one estimated 2 cm
  // above it and one 2 cm below: the best alignment is the identity, so every
  // error is exactly 2 cm.
  Trajectory gt, est;
  for (int i = 0; i < 100; ++i) {
    const int k = i / 2;
    Pose p = Pose::Identity();
    p.translation() = Eigen::Vector3d(std::cos(0.05 * k), 0.5 * std::sin(0.05 * k), 0);
    gt.push_back({i / 30.0, p});
    p.translation().z() += (i % 2 ? 0.02 : -0.02);
    est.push_back({i / 30.0, p});
  }
  const auto e = rekon::eval::evaluateTrajectory(gt, est);
  EXPECT_NEAR(e.ate_rmse_m, 0.02, 1e-9);
  EXPECT_NEAR(e.ate_max_m, 0.02, 1e-9);
}

TEST(EvalTrajectory, ExtraTurningGivesItsRateAsRotationalRpe) {
  // Standing still; the estimate turns at 3 deg/s: RPE rotation is 3 deg/s, translation 0.
  Trajectory gt, est;
  for (int i = 0; i < 90; ++i) {
    const double t = i / 30.0;
    gt.push_back({t, Pose::Identity()});
    Pose p = Pose::Identity();
    p.linear() = Eigen::AngleAxisd(3.0 * kDeg * t, Eigen::Vector3d::UnitY()).toRotationMatrix();
    est.push_back({t, p});
  }
  const auto e = rekon::eval::evaluateTrajectory(gt, est);
  EXPECT_NEAR(e.rpe_rot_deg_per_s, 3.0, 1e-6);
  EXPECT_NEAR(e.rpe_trans_m_per_s, 0.0, 1e-12);
  EXPECT_NEAR(e.ate_rmse_m, 0.0, 1e-12);
  EXPECT_EQ(e.rpe_pairs, 60u);  // frames 0..59 have a partner 1 s later
}

TEST(EvalTrajectory, ExtraSpeedGivesItsRateAsTranslationalRpe) {
  // Walking at 0.5 m/s along x; the estimate walks at 0.6 m/s: RPE 0.1 m/s.
  Trajectory gt, est;
  for (int i = 0; i < 90; ++i) {
    const double t = i / 30.0;
    Pose p = Pose::Identity();
    p.translation().x() = 0.5 * t;
    gt.push_back({t, p});
    p.translation().x() = 0.6 * t;
    est.push_back({t, p});
  }
  EXPECT_NEAR(rekon::eval::evaluateTrajectory(gt, est).rpe_trans_m_per_s, 0.1, 1e-9);
}

TEST(EvalTrajectory, AssociatesTimestampsWithinTheLimitOnly) {
  Trajectory est = walk();
  for (auto& p : est) p.timestamp += 0.005;
  EXPECT_EQ(rekon::eval::evaluateTrajectory(walk(), est).matched, 300u);
  for (auto& p : est) p.timestamp += 100.0;  // another clock: nothing associates
  EXPECT_THROW(rekon::eval::evaluateTrajectory(walk(), est), rekon::Error);
}

TEST(EvalTrajectory, AssociationUsesEachPoseOnce) {
  // Ground truth at 100 Hz, estimate at 30 Hz: each estimate gets its nearest ground truth.
  Trajectory gt, est;
  for (int i = 0; i < 100; ++i) gt.push_back({i / 100.0, Pose::Identity()});
  for (int i = 0; i < 30; ++i) est.push_back({i / 30.0, Pose::Identity()});
  const auto pairs = rekon::eval::associate(gt, est, 0.02);
  ASSERT_EQ(pairs.size(), 30u);
  for (const auto& [g, e] : pairs) EXPECT_LE(std::abs(gt[g].timestamp - est[e].timestamp), 0.005 + 1e-12);
}

TEST(EvalCommand, TrajEndsWithKeyValuesAndJsonOnRequest) {
  rekon::test::TempDir dir;
  rekon::writeTumTrajectory(walk(), dir / "gt.txt");
  std::string out;
  ASSERT_EQ(rekon::test::runCommand(rekon::test::binDir() + "/rekon eval traj " + (dir / "gt.txt") + " " + (dir / "gt.txt"), &out), 0)
      << out;
  const std::string last = out.substr(out.rfind('\n', out.size() - 2) + 1);
  EXPECT_EQ(last.rfind("ate_rmse_m=", 0), 0u) << out;
  EXPECT_NE(last.find(" rpe_trans_m_per_s="), std::string::npos);
  EXPECT_NE(last.find(" rpe_rot_deg_per_s="), std::string::npos);
  ASSERT_EQ(rekon::test::runCommand(rekon::test::binDir() + "/rekon eval traj --json " + (dir / "gt.txt") + " " + (dir / "gt.txt"), &out), 0);
  EXPECT_NE(out.find("\"ate_rmse_m\": "), std::string::npos) << out;
}

}  // namespace
