#pragma once
// A second tracker, built on a different method than rekon's DVO: OpenCV's
// RGB-D odometry from the contrib module (cv::rgbd::RgbdICPOdometry:
// photometric and point-to-plane ICP terms, coarse to fine). Each frame is
// aligned to the current keyframe; a new keyframe starts when the camera has
// moved 10 cm or 10 degrees from it. The covariance of each pose is the
// point-to-plane ICP estimate at the solution, sigma^2 (J^T J)^-1 over the
// frame's points against the keyframe's surface, with sigma^2 from the
// residuals, scaled and floored to match the errors measured against ground
// truth (CvOdometryParams). Free of the bus: the node (node/) and the bench drive it.
#include <opencv2/core/mat.hpp>

#include <cstdint>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/se3.hpp"

namespace cv::rgbd {
class Odometry;
class OdometryFrame;
}  // namespace cv::rgbd

namespace rekon::odometry_cv {

struct CvOdometryParams {
  static constexpr double kDefaultKeyframeTranslation = 0.1;  // metres, as rekon's tracker and the replay
  static constexpr double kDefaultKeyframeRotationDeg = 10.0;
  static constexpr double kDefaultMaxDepth = 4.0;             // metres; farther depth is noise
  static constexpr int kDefaultCovarianceStride = 4;          // every 4th pixel each way for the covariance
  static constexpr double kDefaultCovarianceMaxResidual = 0.05;  // metres: farther pairs are not the same surface
  // The ICP estimate treats every point as independent, and they are not
  // (depth noise and misalignment are correlated over the image): against
  // ground truth it is ~1000x too confident (median chi2 of the frames'
  // errors 8023 on tum_fr3_teddy_200 and 4950 on the first 300 frames of
  // 7scenes_loop_1000, where a calibrated covariance gives 5.35). Scaled by
  // this, between the two (README "Covariance" has the check).
  static constexpr double kDefaultCovarianceScale = 1200.0;
  // Added to every variance: the depth's quantisation leaves at least a
  // millimetre and a milliradian, however much geometry a plane offers.
  static constexpr double kDefaultCovarianceFloorT = 0.001;  // metres
  static constexpr double kDefaultCovarianceFloorR = 0.001;  // radians
  double keyframe_translation = kDefaultKeyframeTranslation;
  double keyframe_rotation_deg = kDefaultKeyframeRotationDeg;
  double max_depth = kDefaultMaxDepth;
  int covariance_stride = kDefaultCovarianceStride;
  double covariance_max_residual = kDefaultCovarianceMaxResidual;
  double covariance_scale = kDefaultCovarianceScale;
  double covariance_floor_t = kDefaultCovarianceFloorT;
  double covariance_floor_r = kDefaultCovarianceFloorR;
};

struct CvTracked {
  int64_t keyframe_id = 0;
  bool new_keyframe = false;  // this frame starts keyframe_id (pose identity)
  bool lost = false;          // no alignment: the pose is the last good one
  Pose pose_in_keyframe = Pose::Identity();
  Pose keyframe_world = Pose::Identity();
  Matrix6d covariance = Matrix6d::Zero();  // of pose_in_keyframe * exp(xi), (v, w); zero for a keyframe itself
};

// How well `covariance` (right perturbation, (v, w)) explains the error of
// `estimate` against `truth`: chi2 = xi^T C^-1 xi, xi = log(estimate^-1 truth);
// 6 on average when the covariance is calibrated. nullopt for a covariance
// that is not positive definite.
std::optional<double> errorChi2(const Pose& estimate, const Matrix6d& covariance, const Pose& truth);

class CvOdometry {
 public:
  CvOdometry(const Intrinsics& intrinsics, const CvOdometryParams& params = {});
  ~CvOdometry();
  CvOdometry(const CvOdometry&) = delete;
  CvOdometry& operator=(const CvOdometry&) = delete;

  // depth: CV_16UC1 in intrinsics.depth_scale units per metre; color: CV_8UC3 BGR.
  CvTracked track(const cv::Mat& depth, const cv::Mat& color);
  // Every keyframe's world pose (chained odometry), ascending id.
  const std::vector<std::pair<int64_t, Pose>>& keyframes() const { return keyframes_; }

 private:
  struct Keyframe;
  cv::Mat depthMetres(const cv::Mat& depth) const;
  void startKeyframe(const cv::Ptr<cv::rgbd::OdometryFrame>& frame, const cv::Mat& depth_m, const Pose& world);
  Matrix6d covariance(const cv::Mat& depth_m, const Pose& pose_in_keyframe) const;

  Intrinsics k_;
  CvOdometryParams params_;
  cv::Mat camera_matrix_;
  cv::Ptr<cv::rgbd::Odometry> odometry_;
  std::unique_ptr<Keyframe> keyframe_;
  std::vector<std::pair<int64_t, Pose>> keyframes_;
  Pose last_pose_ = Pose::Identity();  // the last good pose in the keyframe (the next alignment's start)
};

}  // namespace rekon::odometry_cv
