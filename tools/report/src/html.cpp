#include "rekon/report/html.hpp"

#include "rekon/common/image_io.hpp"
#include "svg_text.hpp"

namespace rekon::report {

std::string base64Encode(const uint8_t* data, size_t size) {
  static constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((size + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < size; i += 3) {
    const uint32_t v = (uint32_t(data[i]) << 16) | (uint32_t(data[i + 1]) << 8) | data[i + 2];
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += kAlphabet[v & 63];
  }
  if (i < size) {
    const bool two = i + 1 < size;
    const uint32_t v = (uint32_t(data[i]) << 16) | (two ? uint32_t(data[i + 1]) << 8 : 0u);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += two ? kAlphabet[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::string escapeHtml(const std::string& text) { return escapeXml(text); }

std::string inlineSvgImage(const std::string& svg, const std::string& alt) {
  return "<img alt=\"" + escapeHtml(alt) + "\" src=\"data:image/svg+xml;base64," + base64Encode(svg) + "\">";
}

std::string inlinePngImage(const cv::Mat& bgr, const std::string& alt) {
  const std::vector<uint8_t> png = encodePng(bgr);
  return "<img alt=\"" + escapeHtml(alt) + "\" src=\"data:image/png;base64," + base64Encode(png.data(), png.size()) + "\">";
}

}  // namespace rekon::report
