// Keyframe fusion (paper section 3): depth weights, eq. (1), color by weighted median, strategies.
#include <gtest/gtest.h>

#include <algorithm>
#include <opencv2/imgproc.hpp>

#include "rekon/common/error.hpp"
#include "rekon/mapper/fusion/keyframe_fusion.hpp"

using namespace rekon;
using namespace rekon::fusion;

namespace {

Intrinsics smallCamera() {
  Intrinsics k;
  k.width = 80;
  k.height = 60;
  k.fx = k.fy = 70.0;
  k.cx = 39.5;
  k.cy = 29.5;
  k.depth_scale = 5000.0;
  return k;
}

// Depth (metres) of the plane n . p = d seen by the camera at the origin.
cv::Mat planeDepth(const Intrinsics& k, const Eigen::Vector3d& n, double d) {
  cv::Mat z(k.height, k.width, CV_32F);
  for (int v = 0; v < k.height; ++v)
    for (int u = 0; u < k.width; ++u) {
      const Eigen::Vector3d ray((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
      z.at<float>(v, u) = static_cast<float>(d / n.dot(ray));
    }
  return z;
}

RgbdFrame frameOf(const cv::Mat& depth_m, const Intrinsics& k, const cv::Scalar& bgr, int64_t id = 0) {
  RgbdFrame f;
  f.id = id;
  depth_m.convertTo(f.depth, CV_16U, k.depth_scale);
  f.color = cv::Mat(depth_m.size(), CV_8UC3, bgr);
  return f;
}

}  // namespace

TEST(DepthWeights, FrontoParallelPlaneWeighsOneOverZSquared) {
  const Intrinsics k = smallCamera();
  const cv::Mat w = depthWeights(planeDepth(k, {0, 0, 1}, 2.0), k, FusionParams{});
  EXPECT_NEAR(w.at<float>(30, 40), 0.25, 1e-5);  // cos 0 / 2^2
}

TEST(DepthWeights, PlaneTiltedSixtyDegreesWeighsHalfAsMuch) {
  // Neighbouring depths differ by about tan(60 deg) / f = 2.5 % < max_depth_step: no discontinuity.
  const Intrinsics k = smallCamera();
  const Eigen::Vector3d n(std::sin(M_PI / 3), 0, std::cos(M_PI / 3));
  const cv::Mat z = planeDepth(k, n, 1.0);
  const cv::Mat w = depthWeights(z, k, FusionParams{});
  const double zc = z.at<float>(30, 40);
  // The normal makes 60 deg with the optical axis only at the image centre column's ray; the
  // weight uses the angle to the camera axis, so cos = n_z = 0.5 everywhere.
  EXPECT_NEAR(w.at<float>(30, 40), 0.5 / (zc * zc), 1e-4 * 0.5 / (zc * zc) + 1e-6);
}

TEST(DepthWeights, PixelsBesideADepthStepAreDropped) {
  const Intrinsics k = smallCamera();
  cv::Mat z(k.height, k.width, CV_32F, cv::Scalar(1.0));
  z.colRange(40, k.width).setTo(2.0);  // a 1 m step between columns 39 and 40
  const cv::Mat w = depthWeights(z, k, FusionParams{});
  EXPECT_EQ(w.at<float>(30, 39), 0.0f);
  EXPECT_EQ(w.at<float>(30, 40), 0.0f);
  EXPECT_NEAR(w.at<float>(30, 37), 1.0, 1e-5);   // 1 / 1^2, two pixels away
  EXPECT_NEAR(w.at<float>(30, 42), 0.25, 1e-5);  // 1 / 2^2
}

TEST(KeyframeFusion, TwoDepthsAtOnePoseAverageByTheirWeights) {
  // Eq. (1): Z* = (w1 Z1 + w2 Z2) / (w1 + w2), W* = w1 + w2, with w = 1 / Z^2 on a fronto-parallel plane.
  const Intrinsics k = smallCamera();
  KeyframeFuser fuser(FusionParams{}, k);
  fuser.begin(0, 0, Pose::Identity(), Pose::Identity());
  fuser.add(frameOf(planeDepth(k, {0, 0, 1}, 2.0), k, {0, 0, 255}), Pose::Identity());
  fuser.add(frameOf(planeDepth(k, {0, 0, 1}, 2.05), k, {0, 0, 255}), Pose::Identity());
  const FusedKeyframe kf = fuser.finish();
  const double w1 = 1 / (2.0 * 2.0), w2 = 1 / (2.05 * 2.05);
  EXPECT_NEAR(kf.depth.at<float>(30, 40), (w1 * 2.0 + w2 * 2.05) / (w1 + w2), 1e-4);
  EXPECT_NEAR(kf.weight.at<float>(30, 40), w1 + w2, 1e-4);
  EXPECT_EQ(kf.frames, 2);
}

TEST(KeyframeFusion, AFrameFromAShiftedPoseLandsOnTheKeyframesPlane) {
  // The keyframe looks at the plane z = 2; a frame 10 cm to the right sees it at 2 m as well.
  // Warped into the keyframe, its pixels keep depth 2 (up to the 0.2 mm depth quantisation).
  const Intrinsics k = smallCamera();
  KeyframeFuser fuser(FusionParams{}, k);
  fuser.begin(0, 0, Pose::Identity(), Pose::Identity());
  Pose shifted = Pose::Identity();
  shifted.translation() = Eigen::Vector3d(0.1, 0, 0);
  fuser.add(frameOf(planeDepth(k, {0, 0, 1}, 2.0), k, {0, 0, 255}), shifted);
  const FusedKeyframe kf = fuser.finish();
  EXPECT_NEAR(kf.depth.at<float>(30, 60), 2.0, 1e-3);
  // The frame sees 0.1 m further right: keyframe columns below u = f * 0.1 / 2 = 3.5 stay empty.
  EXPECT_EQ(kf.depth.at<float>(30, 1), 0.0f);
}

TEST(KeyframeFusion, ColorIsTheWeightedMedianOfTheObservations) {
  // Three flat frames at one pose, two red and one blue, equally weighted: the median is red.
  const Intrinsics k = smallCamera();
  KeyframeFuser fuser(FusionParams{}, k);
  fuser.begin(0, 0, Pose::Identity(), Pose::Identity());
  const cv::Mat z = planeDepth(k, {0, 0, 1}, 2.0);
  fuser.add(frameOf(z, k, {0, 0, 200}), Pose::Identity());
  fuser.add(frameOf(z, k, {200, 0, 0}), Pose::Identity());
  fuser.add(frameOf(z, k, {0, 0, 200}), Pose::Identity());
  const FusedKeyframe kf = fuser.finish();
  EXPECT_EQ(kf.color.at<cv::Vec3b>(30, 40), cv::Vec3b(0, 0, 200));
}

TEST(Blurriness, ABlurredImageScoresHigherThanTheSharpOne) {
  cv::Mat checker(120, 160, CV_8UC3);
  for (int y = 0; y < checker.rows; ++y)
    for (int x = 0; x < checker.cols; ++x)
      checker.at<cv::Vec3b>(y, x) = ((x / 8 + y / 8) % 2) ? cv::Vec3b(230, 230, 230) : cv::Vec3b(20, 20, 20);
  cv::Mat blurred;
  cv::GaussianBlur(checker, blurred, cv::Size(0, 0), 3.0);
  const double sharp = blurriness(checker), soft = blurriness(blurred);
  EXPECT_LT(sharp, 0.3);        // hard edges: the 9-tap re-blur removes most neighbour variation
  EXPECT_GT(soft, sharp + 0.2);  // already smooth: the re-blur removes little
}

TEST(KeyframeStrategy, ConstStartsANewKeyframeAfterKappaFrames) {
  const Intrinsics k = smallCamera();
  FusionParams p;
  p.kappa = 3;
  KeyframeFuser fuser(p, k);
  EXPECT_TRUE(fuser.startsNewKeyframe(0, Pose::Identity()));  // none open yet
  fuser.begin(0, 0, Pose::Identity(), Pose::Identity());
  const RgbdFrame f = frameOf(planeDepth(k, {0, 0, 1}, 2.0), k, {0, 0, 200});
  for (int i = 0; i < 3; ++i) {
    EXPECT_FALSE(fuser.startsNewKeyframe(0, Pose::Identity())) << i;
    fuser.add(f, Pose::Identity());
  }
  EXPECT_TRUE(fuser.startsNewKeyframe(0, Pose::Identity()));
}

TEST(KeyframeStrategy, DvoFollowsTheDvoKeyframeAndDistTheThresholds) {
  const Intrinsics k = smallCamera();
  const RgbdFrame f = frameOf(planeDepth(k, {0, 0, 1}, 2.0), k, {0, 0, 200});
  FusionParams dvo;
  dvo.strategy = KeyframeStrategy::kDvo;
  KeyframeFuser a(dvo, k);
  a.begin(0, 7, Pose::Identity(), Pose::Identity());
  a.add(f, Pose::Identity());
  EXPECT_FALSE(a.startsNewKeyframe(7, Pose::Identity()));
  EXPECT_TRUE(a.startsNewKeyframe(8, Pose::Identity()));

  FusionParams dist;
  dist.strategy = KeyframeStrategy::kDist;  // 0.1 m, 10 deg
  KeyframeFuser b(dist, k);
  b.begin(0, 0, Pose::Identity(), Pose::Identity());
  b.add(f, Pose::Identity());
  Pose near = Pose::Identity(), far = Pose::Identity();
  near.translation() = Eigen::Vector3d(0.09, 0, 0);
  far.translation() = Eigen::Vector3d(0.11, 0, 0);
  EXPECT_FALSE(b.startsNewKeyframe(0, near));
  EXPECT_TRUE(b.startsNewKeyframe(0, far));
}

TEST(KeyframeStrategy, OverlapDropsWhenTheCameraTurnsAway) {
  const Intrinsics k = smallCamera();
  FusionParams p;
  p.strategy = KeyframeStrategy::kOverlap;  // below 70 % of the keyframe's pixels in view
  KeyframeFuser fuser(p, k);
  fuser.begin(0, 0, Pose::Identity(), Pose::Identity());
  fuser.add(frameOf(planeDepth(k, {0, 0, 1}, 2.0), k, {0, 0, 200}), Pose::Identity());
  Pose small_turn = Pose::Identity(), big_turn = Pose::Identity();
  // The image spans +-30 deg horizontally (atan(40 / 70)): 5 deg keeps most of it, 30 deg about half.
  small_turn.linear() = Eigen::AngleAxisd(5 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
  big_turn.linear() = Eigen::AngleAxisd(30 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
  EXPECT_FALSE(fuser.startsNewKeyframe(0, small_turn));
  EXPECT_TRUE(fuser.startsNewKeyframe(0, big_turn));
}

// A still camera (the same frame at the same pose, the same DVO keyframe):
// dvo, dist and overlap never start a new KF keyframe on their own, so the
// cap closes one every max_frames_per_keyframe frames and the color input
// held never exceeds the cap's worth (it grew by one frame each frame before).
TEST(KeyframeStrategy, EveryStrategyClosesAKeyframeAtTheCapForAStillCamera) {
  const Intrinsics k = smallCamera();
  const RgbdFrame f = frameOf(planeDepth(k, {0, 0, 1}, 2.0), k, {0, 0, 200});
  constexpr int kCap = 7, kFrames = 100;
  for (const KeyframeStrategy s : {KeyframeStrategy::kDvo, KeyframeStrategy::kDist, KeyframeStrategy::kOverlap}) {
    FusionParams p;
    p.strategy = s;
    p.max_frames_per_keyframe = kCap;
    KeyframeFuser fuser(p, k);
    int keyframes = 0;
    size_t peak_bytes = 0, one_frame_bytes = 0;
    for (int i = 0; i < kFrames; ++i) {
      if (fuser.startsNewKeyframe(0, Pose::Identity())) {
        if (fuser.active()) fuser.finish();
        fuser.begin(keyframes++, 0, Pose::Identity(), Pose::Identity());
      }
      fuser.add(f, Pose::Identity());
      if (i == 0) one_frame_bytes = fuser.heldInputBytes();
      peak_bytes = std::max(peak_bytes, fuser.heldInputBytes());
      ASSERT_LE(fuser.frames(), kCap) << toString(s);
    }
    EXPECT_EQ(keyframes, (kFrames + kCap - 1) / kCap) << toString(s);
    EXPECT_GT(one_frame_bytes, 0u);
    EXPECT_EQ(peak_bytes, kCap * one_frame_bytes) << toString(s);
  }
}

TEST(KeyframeStrategy, ConstKappaAboveTheCapIsAnErrorNamingBothKeys) {
  FusionParams p;
  p.kappa = 60;
  p.max_frames_per_keyframe = 50;
  try {
    p.validate();
    ADD_FAILURE() << "kappa above the cap accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("mapper.kappa"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("max_frames_per_keyframe"), std::string::npos) << e.what();
  }
  p.strategy = KeyframeStrategy::kDvo;  // kappa is not used by the other strategies
  EXPECT_NO_THROW(p.validate());
}
