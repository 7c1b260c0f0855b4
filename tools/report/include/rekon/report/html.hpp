#pragma once
// Pieces of a self-contained HTML page: base64 data URIs instead of files.
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

namespace rekon::report {

// RFC 4648 base64 with padding.
std::string base64Encode(const uint8_t* data, size_t size);
inline std::string base64Encode(const std::string& bytes) {
  return base64Encode(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
}

// `<img>` elements whose source is inside the page.
std::string inlineSvgImage(const std::string& svg, const std::string& alt);
std::string inlinePngImage(const cv::Mat& bgr, const std::string& alt);

std::string escapeHtml(const std::string& text);

}  // namespace rekon::report
