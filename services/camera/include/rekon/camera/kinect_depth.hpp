#pragma once
// The Kinect v1's raw depth as libfreenect delivers it in FREENECT_DEPTH_11BIT
// (an 11-bit disparity per pixel of the IR camera) turned into millimetres
// registered to the color camera: the disparity model, a rigid warp from the
// IR camera into the color camera, and the calibration file that holds both.
//
// Calibration (camera.yaml, --calibration FILE): the color camera in the keyed
// form of common/camera.hpp, plus optional keys for devices whose depth is
// not registered in hardware:
//   depth_camera: {fx: 580, fy: 580, cx: 319.5, cy: 239.5}  # IR intrinsics, same width/height as color
//   depth_to_color_translation: [-0.025, 0, 0]              # metres: p_color = R p_depth + t
//   depth_to_color_rotation: [1, 0, 0, 0, 1, 0, 0, 0, 1]    # row-major; default identity
//   disparity: [3.3309495161, -0.0030711016]                # c0, c1: depth_m = 1 / (c0 + c1 raw)
// Without depth_camera the depth is taken as already aligned with color (same
// intrinsics, identity transform); the rotation and translation keys then are
// an error (they would be ignored). depth_scale of the color camera is read
// but the camera's frames are always in millimetres.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <opencv2/core/mat.hpp>
#include <string>

#include "rekon/common/camera.hpp"

namespace rekon::camera {

// depth_m = 1 / (c0 + c1 * raw): the model fitted by Nicolas Burrus to the
// Kinect v1 and used by ROS's openni/freenect drivers and RGBDemo.
struct DisparityModel {
  static constexpr double kDefaultC0 = 3.3309495161;
  static constexpr double kDefaultC1 = -0.0030711016;
  double c0 = kDefaultC0;
  double c1 = kDefaultC1;
};

// The model as a lookup table over the 2048 raw values.
class DisparityTable {
 public:
  static constexpr uint16_t kNoValue = 2047;  // FREENECT_DEPTH_RAW_NO_VALUE
  static constexpr int kSize = 2048;

  explicit DisparityTable(const DisparityModel& model = {});
  // Metres for a raw value; 0 for kNoValue, values >= kSize, and raw values
  // whose denominator is not positive (beyond the model's range).
  float metres(uint16_t raw) const { return raw < kSize ? metres_[raw] : 0.0f; }
  // The raw value whose depth is nearest to `metres`; kNoValue for 0, a
  // non-finite value or a depth no raw value reaches within half a step.
  uint16_t nearestRaw(double metres) const;
  // A raw image (CV_16UC1) in metres (CV_32FC1, 0 = none).
  cv::Mat toMetres(const cv::Mat& raw) const;
  const DisparityModel& model() const { return model_; }

 private:
  DisparityModel model_;
  std::array<float, kSize> metres_{};
  int last_valid_ = -1;  // largest raw value with a depth
};

// Where the depth camera sits relative to the color camera.
struct KinectCalibration {
  Intrinsics color;  // the camera the frames are registered to
  Intrinsics depth;  // the IR camera (= color when aligned)
  Eigen::Matrix3d depth_to_color_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d depth_to_color_translation = Eigen::Vector3d::Zero();  // metres
  DisparityModel disparity;
  bool aligned = true;  // no depth_camera key: depth is already in the color camera

  // A Kinect v1 that nobody calibrated: color fx = fy = 525 (cx 319.5, cy
  // 239.5), IR fx = fy = 580 (cx 319.5, cy 239.5), the color camera 2.5 cm to
  // the right of the IR camera as the device looks (t = (-0.025, 0, 0), ROS
  // openni_launch's nominal frames), the default disparity model. Good to a
  // few pixels at most; calibrate for better.
  static KinectCalibration nominal();
};

// Parses camera.yaml text (see the top of this file); throws rekon::Error
// naming `source` and the key for a bad value.
KinectCalibration parseKinectCalibration(const std::string& text, const std::string& source);
KinectCalibration loadKinectCalibration(const std::string& path);
// Writes the keys parseKinectCalibration reads (depth keys only when not aligned).
void saveKinectCalibration(const KinectCalibration& calibration, const std::string& path);

// A rigid warp of depth images from one pinhole camera into another:
// unproject, transform, project, nearest depth per target pixel (z-buffer),
// no hole filling (like libfreenect's own registration). The rays of the
// source pixels are computed once.
class DepthWarp {
 public:
  DepthWarp(const Intrinsics& from, const Intrinsics& to, const Eigen::Matrix3d& rotation,
            const Eigen::Vector3d& translation);
  // Depth in metres (CV_32FC1, `from` size, 0 = none) -> depth in metres
  // along the target camera's z (CV_32FC1, `to` size, 0 = none).
  cv::Mat apply(const cv::Mat& depth_m) const;

 private:
  Intrinsics to_;
  Eigen::Vector3f translation_;
  cv::Mat rays_;  // CV_32FC3: rotation * K_from^-1 (u, v, 1) per source pixel
};

// Metres (CV_32FC1) to millimetres (CV_16UC1, rounded; 0 for none and for
// depths beyond 65.535 m).
cv::Mat toMillimetres(const cv::Mat& depth_m);

// Raw 11-bit IR-camera depth (CV_16UC1) -> millimetres registered to the color
// camera (CV_16UC1, color size), the whole software path of a raw device.
class KinectRegistration {
 public:
  explicit KinectRegistration(const KinectCalibration& calibration);
  cv::Mat apply(const cv::Mat& raw) const;

 private:
  KinectCalibration calibration_;
  DisparityTable table_;
  DepthWarp warp_;
};

}  // namespace rekon::camera
