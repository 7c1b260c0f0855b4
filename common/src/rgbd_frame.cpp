#include "rekon/common/rgbd_frame.hpp"

namespace rekon {
namespace {

uint64_t fnv1a(const cv::Mat& m, uint64_t h) {
  for (int r = 0; r < m.rows; ++r) {
    const uint8_t* p = m.ptr<uint8_t>(r);
    const size_t n = static_cast<size_t>(m.cols) * m.elemSize();
    for (size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 1099511628211ull;
  }
  return h;
}

}  // namespace

uint64_t frameHash(const RgbdFrame& frame) { return fnv1a(frame.color, fnv1a(frame.depth, 14695981039346656037ull)); }

}  // namespace rekon
