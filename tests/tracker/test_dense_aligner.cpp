// The dense aligner on rendered frames with exact ground truth.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <opencv2/imgproc.hpp>

#include "rekon/tracker/dense_aligner.hpp"
#include "rekon/tracker/keyframe_reference.hpp"
#include "rekon/tracker/rgbd_pyramid.hpp"
#include "synthetic_views.hpp"

namespace rekon::tracker {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

Pose motion(double tx, double ty, double tz, double angle_deg, const Eigen::Vector3d& axis) {
  Pose m = Pose::Identity();
  m.linear() = Eigen::AngleAxisd(angle_deg * kDeg, axis.normalized()).toRotationMatrix();
  m.translation() = Eigen::Vector3d(tx, ty, tz);
  return m;
}

struct Pair {
  RgbdPyramid reference_pyramid, current;
  KeyframeReference reference;
};

Pair makePair(const RgbdFrame& ref, const RgbdFrame& cur, const Intrinsics& k, const AlignerParams& p) {
  Pair out;
  out.reference_pyramid.build(ref, k, p.finest_level, p.coarsest_level, p.min_depth, p.max_depth);
  out.current.build(cur, k, p.finest_level, p.coarsest_level, p.min_depth, p.max_depth);
  out.reference = KeyframeReference(out.reference_pyramid, p);
  return out;
}

double translationError(const Pose& a, const Pose& b) { return (a.translation() - b.translation()).norm(); }
double rotationErrorDeg(const Pose& a, const Pose& b) { return rotationAngle(a, b) / kDeg; }

class DenseAlignerTest : public ::testing::Test {
 protected:
  test::RoomViews room;
  // A view of the room from its trajectory, and the same view after a small
  // motion of the size of one to three frames of hand-held motion at 30 Hz.
  Pose reference_pose = room.trajectory(60)[30].pose;
  Pose truth = motion(0.015, -0.01, 0.02, 1.5, Eigen::Vector3d(0.3, 1.0, -0.2));  // current in reference
  RgbdFrame reference = room.render(reference_pose);
  RgbdFrame current = room.render(reference_pose * truth);
};

TEST_F(DenseAlignerTest, RecoversAKnownSmallMotionWithin1mmAnd0_1DegreeWithoutNoise) {
  const AlignerParams p;  // defaults: levels 3 -> 1
  Pair pair = makePair(reference, current, room.intrinsics(), p);
  DenseAligner aligner(p);
  const AlignResult r = aligner.align(pair.reference, pair.current, Pose::Identity());
  ASSERT_TRUE(r.valid);
  EXPECT_LT(translationError(r.pose, truth), 0.001);  // the bound: 1 mm
  EXPECT_LT(rotationErrorDeg(r.pose, truth), 0.1);    // and 0.1 degree
  EXPECT_TRUE(r.converged);
}

TEST_F(DenseAlignerTest, ReportsPositiveDefiniteInformationEntropyAndConstrainingPixels) {
  const AlignerParams p;
  Pair pair = makePair(reference, current, room.intrinsics(), p);
  DenseAligner aligner(p);
  const AlignResult r = aligner.align(pair.reference, pair.current, Pose::Identity());
  ASSERT_TRUE(r.valid);
  EXPECT_EQ(Eigen::LLT<Matrix6d>(r.information).info(), Eigen::Success);
  EXPECT_TRUE(std::isfinite(r.entropy));
  EXPECT_DOUBLE_EQ(r.entropy, entropyOfInformation(r.information));
  // Thousands of textured pixels constrain a 320x240 alignment; the warped
  // count cannot exceed the keyframe's selection.
  EXPECT_GT(r.valid_pixels, 2000);
  EXPECT_LE(r.valid_pixels, r.selected_pixels);
  // The covariance is the inverse of the information.
  EXPECT_LT((r.covariance() * r.information - Matrix6d::Identity()).cwiseAbs().maxCoeff(), 1e-6);
}

TEST_F(DenseAlignerTest, PaintedOverRegionBarelyMovesTheEstimate) {
  // An occluder the keyframe never saw: a flat white card 0.6 m in front of
  // the camera covering 1/12 of the image (about 25 000 pixels at 640x480).
  RgbdFrame painted = current;
  painted.color = current.color.clone();
  painted.depth = current.depth.clone();
  const cv::Rect card(380, 260, 200, 128);
  painted.color(card).setTo(cv::Scalar(250, 250, 250));
  painted.depth(card).setTo(cv::Scalar(static_cast<int>(0.6 * room.intrinsics().depth_scale)));
  const AlignerParams p;
  Pair pair = makePair(reference, painted, room.intrinsics(), p);
  DenseAligner aligner(p);
  const AlignResult r = aligner.align(pair.reference, pair.current, Pose::Identity());
  ASSERT_TRUE(r.valid);
  // The t-distribution weights give the card's huge residuals almost no
  // weight: the estimate stays within 2 mm and 0.2 degree of the truth.
  EXPECT_LT(translationError(r.pose, truth), 0.002);
  EXPECT_LT(rotationErrorDeg(r.pose, truth), 0.2);
}

TEST_F(DenseAlignerTest, AlignsTwoKeyframesFromAnInitialGuessAsLoopClosuresDo) {
  // Two views 12 cm and 6 degrees apart, aligned from a guess 4 cm and 3
  // degrees off the truth (a drifted pose-graph estimate).
  const Pose far = motion(0.08, 0.03, 0.08, 6.0, Eigen::Vector3d(0.1, 1.0, 0.3));
  const RgbdFrame other = room.render(reference_pose * far, synth::Noise::Kinect, 7);
  const AlignerParams p;
  Pair pair = makePair(reference, other, room.intrinsics(), p);
  DenseAligner aligner(p);
  const Pose guess = far * motion(0.03, -0.02, 0.015, 3.0, Eigen::Vector3d(1, 0, 0));
  const AlignResult r = aligner.align(pair.reference, pair.current, guess);
  ASSERT_TRUE(r.valid);
  // Kinect-like noise: a few millimetres and a few tenths of a degree.
  EXPECT_LT(translationError(r.pose, far), 0.005);
  EXPECT_LT(rotationErrorDeg(r.pose, far), 0.3);
}

TEST_F(DenseAlignerTest, RunsOnTheLevelsTheCallerChoosesForACoarseStage) {
  // Loop-closure checks first align coarsely (levels 3 -> 2 here), then finely.
  const AlignerParams p;
  Pair pair = makePair(reference, current, room.intrinsics(), p);
  DenseAligner aligner(p);
  const AlignResult coarse = aligner.align(pair.reference, pair.current, Pose::Identity(), 3, 2);
  ASSERT_TRUE(coarse.valid);
  EXPECT_EQ(coarse.selected_pixels, pair.reference.level(2).count);
  EXPECT_LT(translationError(coarse.pose, truth), 0.002);  // 160x120: still within 2 mm without noise
  const AlignResult fine = aligner.align(pair.reference, pair.current, coarse.pose, 1, 1);
  ASSERT_TRUE(fine.valid);
  EXPECT_LT(translationError(fine.pose, truth), 0.001);
  EXPECT_LT(rotationErrorDeg(fine.pose, truth), 0.1);
}

TEST_F(DenseAlignerTest, FailsWithTheInitialPoseWhenNothingOverlaps) {
  const AlignerParams p;
  Pair pair = makePair(reference, current, room.intrinsics(), p);
  DenseAligner aligner(p);
  // Facing away: every keyframe point lands behind the camera.
  const Pose away = motion(0, 0, 0, 180.0, Eigen::Vector3d(0, 1, 0));
  const AlignResult r = aligner.align(pair.reference, pair.current, away);
  EXPECT_FALSE(r.valid);
  EXPECT_TRUE(isValidPose(r.pose));
  EXPECT_LT(translationError(r.pose, away), 1e-12);
}

}  // namespace
}  // namespace rekon::tracker
