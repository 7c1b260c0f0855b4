#pragma once
// PNG and JPEG on libpng and libjpeg(-turbo) directly. OpenCV's imgcodecs,
// as Debian builds it, pulls 141 shared libraries into every process (GDAL,
// GDCM, poppler, HDF5, ...): 0.18 s to start and ~40 MB of RSS each.
// Internal to image_io.cpp, which checks a file's header and completeness
// before it comes here; errors are rekon::Error lines naming `what`.
#include <opencv2/core.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace rekon::detail {

// A 16-bit single-channel PNG (depth), in the host's byte order.
cv::Mat decodePngGray16(const uint8_t* data, size_t size, const std::string& what);
// Any PNG as 8-bit BGR (palette and grey expanded, alpha dropped, 16 bits
// cut to their high byte).
cv::Mat decodePngBgr(const uint8_t* data, size_t size, const std::string& what);
// A baseline or progressive JPEG as 8-bit BGR (grey expanded). EXIF
// orientation is not applied.
cv::Mat decodeJpegBgr(const uint8_t* data, size_t size, const std::string& what);

// CV_8UC1, CV_8UC3 (BGR), CV_8UC4 (BGRA) or CV_16UC1; zlib level 0-9.
std::vector<uint8_t> encodePngImage(const cv::Mat& image, int level);
// CV_8UC1 or CV_8UC3 (BGR); quality 1-100.
std::vector<uint8_t> encodeJpegImage(const cv::Mat& image, int quality);

}  // namespace rekon::detail
