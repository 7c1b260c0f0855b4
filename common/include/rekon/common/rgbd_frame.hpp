#pragma once
// One RGB-D frame as rekon passes it around: raw 16-bit depth (units of
// Intrinsics::depth_scale per metre, 0 = no measurement) and 8-bit BGR color
// (OpenCV's channel order) of the same size.
#include <opencv2/core/mat.hpp>

#include <cstdint>

namespace rekon {

struct RgbdFrame {
  int64_t id = 0;
  double timestamp = 0.0;
  cv::Mat depth;  // CV_16UC1
  cv::Mat color;  // CV_8UC3, BGR
};

}  // namespace rekon
