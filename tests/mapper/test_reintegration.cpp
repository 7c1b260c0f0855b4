// Selection of the KF keyframes to re-integrate (paper section 4.3, eq. 3 and Figure 4).
#include <gtest/gtest.h>

#include <cmath>

#include "rekon/common/error.hpp"
#include "rekon/mapper/reintegration.hpp"

using namespace rekon::mapper;

namespace {
// The distances of the paper's Figure 4, frames 1..15.
const std::vector<double> kFigure4 = {1, 3, 4, 3, 5, 4, 1, 7, 2, 1, 1, 8, 6, 2, 0};

std::vector<size_t> oneBased(std::vector<size_t> v) {
  for (size_t& i : v) ++i;
  return v;
}
}  // namespace

TEST(Reintegration, Figure4ConsecutiveSelectsFrames4To8) {
  // Window sums (m = 5) from frame 1: 16 19 17 20 19 15 12 19 18 18 17; the
  // largest, 20, starts at frame 4 (3 + 5 + 4 + 1 + 7).
  EXPECT_EQ(oneBased(selectConsecutive(kFigure4, 5)), (std::vector<size_t>{4, 5, 6, 7, 8}));
}

TEST(Reintegration, Figure4MostMovedSelectsFrames12_8_13_5_3) {
  // BundleFusion's choice in the figure: distances 8, 7, 6, 5, then the first 4 (frame 3 before frame 6).
  EXPECT_EQ(oneBased(selectMostMoved(kFigure4, 5)), (std::vector<size_t>{12, 8, 13, 5, 3}));
}

TEST(Reintegration, FewerKeyframesThanMTakesAllThatMoved) {
  // K = 3 < m = 10: the only window is all of them; the unmoved middle one is left alone.
  EXPECT_EQ(selectConsecutive({0.5, 0.0, 0.2}, 10), (std::vector<size_t>{0, 2}));
}

TEST(Reintegration, NothingMovedSelectsNothing) {
  EXPECT_TRUE(selectConsecutive({0, 0, 0, 0}, 2).empty());
  EXPECT_TRUE(selectMostMoved({0, 0, 0, 0}, 2).empty());
}

TEST(Reintegration, ANearSlackPicksTheNearestOfTheWindowsThatMovedNearlyAsMuch) {
  // Figure 4 with m = 5: sums 16 19 17 20 19 15 12 19 18 18 17. Distances from
  // the camera fall along the trajectory (keyframe 15 is the newest).
  std::vector<double> distance;
  for (int i = 15; i >= 1; --i) distance.push_back(i);
  EXPECT_EQ(oneBased(selectConsecutive(kFigure4, 5, 0.0, distance, 0.0)), (std::vector<size_t>{4, 5, 6, 7, 8}));
  // Within 6 % of 20 (>= 18.8): windows from 2, 4, 5 and 8; the nearest starts at 8.
  EXPECT_EQ(oneBased(selectConsecutive(kFigure4, 5, 0.0, distance, 0.06)), (std::vector<size_t>{8, 9, 10, 11, 12}));
  // Within 16 % (>= 16.8): also 3, 9, 10 and 11; the nearest starts at 11 (keyframe 15 did not move).
  EXPECT_EQ(oneBased(selectConsecutive(kFigure4, 5, 0.0, distance, 0.16)), (std::vector<size_t>{11, 12, 13, 14}));
  EXPECT_THROW(selectConsecutive(kFigure4, 5, 0.0, distance, 1.0), rekon::Error);
}

TEST(Reintegration, ZeroMIsAnError) { EXPECT_THROW(selectConsecutive({1, 2}, 0), rekon::Error); }

TEST(PoseMovement, TranslationCountsOnceRotationTwice) {
  const rekon::Pose a = rekon::Pose::Identity();
  rekon::Pose moved = a;
  moved.translation() = Eigen::Vector3d(0.3, 0.0, 0.4);
  EXPECT_NEAR(poseMovement(a, moved), 0.5, 1e-12);  // |(0.3, 0, 0.4)| with scale 1
  rekon::Pose turned = a;
  turned.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_NEAR(poseMovement(a, turned), 0.2, 1e-12);  // yaw 0.1 rad with scale 2
}

TEST(PoseMovement, AnglesWrapAroundPi) {
  // Yaw 179 deg vs -179 deg is 2 degrees apart, not 358.
  rekon::Pose a = rekon::Pose::Identity(), b = rekon::Pose::Identity();
  a.linear() = Eigen::AngleAxisd(179.0 * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  b.linear() = Eigen::AngleAxisd(-179.0 * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_NEAR(poseMovement(a, b), 2 * (2.0 * M_PI / 180), 1e-9);
}

TEST(Reintegration, ModesParseAndUnknownOnesNameTheKey) {
  EXPECT_EQ(parseReintegrationMode("consecutive"), ReintegrationMode::kConsecutive);
  EXPECT_EQ(parseReintegrationMode("most_moved"), ReintegrationMode::kMostMoved);
  EXPECT_EQ(parseReintegrationMode("none"), ReintegrationMode::kNone);
  EXPECT_TRUE(selectForReintegration(ReintegrationMode::kNone, kFigure4, 5, 0.0).empty());
  try {
    parseReintegrationMode("all");
    FAIL();
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("mapper.reintegration"), std::string::npos);
  }
}
