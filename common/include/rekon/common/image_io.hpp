#pragma once
// Reading and encoding the images of an RGB-D frame, with checks that turn a
// corrupt, truncated or mis-sized file into one clear rekon::Error.
#include <opencv2/core/mat.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace rekon {

// The bytes of a file; throws rekon::Error naming it when it cannot be read.
std::vector<uint8_t> readFileBytes(const std::string& path);

// 16-bit single-channel depth (PNG, or binary PGM with maxval 65535) of
// exactly width x height.
cv::Mat readDepthImage(const std::string& path, int width, int height);
// 8-bit color (PNG, JPEG or binary PPM; gray PNG/JPEG is expanded to BGR) of
// exactly width x height.
cv::Mat readColorImage(const std::string& path, int width, int height);

std::vector<uint8_t> encodePng(const cv::Mat& image);
std::vector<uint8_t> encodeJpeg(const cv::Mat& image, int quality = 95);
// Decoding with the same checks; `what` names the source in errors.
cv::Mat decodeDepthPng(const uint8_t* data, size_t size, int width, int height, const std::string& what);
cv::Mat decodeColor(const uint8_t* data, size_t size, int width, int height, const std::string& what);

void writeImage(const std::string& path, const cv::Mat& image);
// Uncompressed binary Netpbm, the fastest lossless way to disk: 16-bit depth
// (CV_16UC1) as P5 PGM, BGR color (CV_8UC3) as P6 PPM. Throws naming `path`.
void writeNetpbm(const std::string& path, const cv::Mat& image);

}  // namespace rekon
