#pragma once
// One RGB-D frame as rekon passes it around: raw 16-bit depth (units of
// Intrinsics::depth_scale per metre, 0 = no measurement) and 8-bit BGR color
// (OpenCV's channel order) of the same size.
#include <opencv2/core/mat.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace rekon {

struct RgbdFrame {
  int64_t id = 0;
  double timestamp = 0.0;
  cv::Mat depth;  // CV_16UC1
  cv::Mat color;  // CV_8UC3, BGR
};

// FNV-1a hash of the depth and color pixels: equal hashes mean bit-identical
// images (used to prove that frames cross the transport unchanged).
uint64_t frameHash(const RgbdFrame& frame);

// The encoded images of one frame, as stored on disk: 16-bit depth PNG and
// color as JPEG or PNG.
struct EncodedFrame {
  std::vector<uint8_t> depth_png;
  std::vector<uint8_t> color;
  std::string color_format;  // "jpeg" or "png"
};

}  // namespace rekon
