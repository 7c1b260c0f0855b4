// rekon-odometry_cv's tracker in process on real frames: it tracks, and its
// covariance explains its errors against the ground truth (the calibration
// in CvOdometryParams), on the first frames of tum_fr3_teddy_200.
#include <gtest/gtest.h>

#include <algorithm>
#include <vector>

#include "rekon/common/dataset.hpp"
#include "rekon/odometry_cv/cv_odometry.hpp"
#include "test_support.hpp"

namespace {

using rekon::odometry_cv::CvOdometry;
using rekon::odometry_cv::CvTracked;

const rekon::Pose* truthAt(const rekon::Trajectory& truth, double timestamp) {
  const int i = rekon::nearestInTime(truth, timestamp, 0.02);
  return i < 0 ? nullptr : &truth[static_cast<size_t>(i)].pose;
}

}  // namespace

TEST(CvOdometry, TracksTeddyWithACovarianceThatExplainsItsErrors) {
  REKON_REQUIRE_DATASET(data, "tum_fr3_teddy_200");
  rekon::DatasetOptions options;
  options.max_frames = 80;
  const rekon::TumDataset dataset(data, options);
  const rekon::Trajectory truth = rekon::readTumTrajectory(data + "/groundtruth.txt");
  CvOdometry odometry(dataset.intrinsics());
  std::vector<double> chi2;
  double keyframe_timestamp = 0;
  int lost = 0;
  for (size_t i = 0; i < dataset.size(); ++i) {
    const rekon::RgbdFrame f = dataset.load(i);
    const CvTracked t = odometry.track(f.depth, f.color);
    lost += t.lost;
    if (t.new_keyframe) {
      keyframe_timestamp = f.timestamp;
      EXPECT_TRUE(t.covariance.isZero());  // the keyframe's own frame: identity by definition
      continue;
    }
    const rekon::Pose* kf = truthAt(truth, keyframe_timestamp);
    const rekon::Pose* now = truthAt(truth, f.timestamp);
    if (t.lost || !kf || !now) continue;
    const auto c = rekon::odometry_cv::errorChi2(t.pose_in_keyframe, t.covariance, kf->inverse() * *now);
    ASSERT_TRUE(c.has_value()) << "frame " << i << ": covariance not positive definite";
    chi2.push_back(*c);
  }
  EXPECT_EQ(lost, 0);
  ASSERT_GT(chi2.size(), 50u);
  std::nth_element(chi2.begin(), chi2.begin() + static_cast<long>(chi2.size() / 2), chi2.end());
  const double median = chi2[chi2.size() / 2];
  std::printf("median chi2 of %zu frames' errors: %.2f (5.35 when calibrated)\n", chi2.size(), median);
  // Measured 3.74 (the same every run: the odometry is deterministic); the
  // ICP estimate without its calibration gives thousands here (8023 over
  // all 193 frames), a covariance inflated 4x would give under 1. Bounds:
  // about half and twice the measured value.
  EXPECT_GT(median, 2.0);
  EXPECT_LT(median, 8.0);
}
