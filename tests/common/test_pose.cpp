#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "rekon/common/error.hpp"
#include "rekon/common/pose.hpp"
#include "test_support.hpp"

TEST(Pose, NaNAndNonOrthonormalPosesAreInvalid) {
  rekon::Pose p = rekon::Pose::Identity();
  EXPECT_TRUE(rekon::isValidPose(p));
  p(0, 3) = std::nan("");
  EXPECT_FALSE(rekon::isValidPose(p));
  rekon::Pose q = rekon::Pose::Identity();
  q.linear()(0, 0) = 1.5;
  EXPECT_FALSE(rekon::isValidPose(q));
  EXPECT_THROW(rekon::requireValidPose(q, "test"), rekon::Error);
}

TEST(Pose, TumTrajectoryRoundTrips) {
  rekon::test::TempDir dir;
  rekon::Trajectory t;
  for (int i = 0; i < 5; ++i) {
    const Eigen::Quaterniond q(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d(0.3, 1, 0.2).normalized()));
    t.push_back({i / 30.0, rekon::poseFromQuatTrans(q, Eigen::Vector3d(i, -i, 0.5 * i))});
  }
  rekon::writeTumTrajectory(t, dir / "t.txt");
  const auto r = rekon::readTumTrajectory(dir / "t.txt");
  ASSERT_EQ(r.size(), t.size());
  for (size_t i = 0; i < t.size(); ++i) {
    EXPECT_NEAR(r[i].timestamp, t[i].timestamp, 1e-6);
    EXPECT_LT((r[i].pose.matrix() - t[i].pose.matrix()).cwiseAbs().maxCoeff(), 1e-8);
  }
}

TEST(Pose, MalformedTrajectoryLineNamesFileAndLine) {
  rekon::test::TempDir dir;
  std::ofstream(dir / "t.txt") << "# header\n0 0 0 0 0 0 0 1\n1 2 3\n";
  try {
    rekon::readTumTrajectory(dir / "t.txt");
    FAIL();
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("t.txt:3"), std::string::npos) << e.what();
  }
}

TEST(Pose, NaNInTrajectoryIsRejected) {
  rekon::test::TempDir dir;
  std::ofstream(dir / "t.txt") << "0 nan 0 0 0 0 0 1\n";
  EXPECT_THROW(rekon::readTumTrajectory(dir / "t.txt"), rekon::Error);
}
