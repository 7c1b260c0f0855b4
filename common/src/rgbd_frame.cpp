#include "rekon/common/rgbd_frame.hpp"

#include "rekon/common/files.hpp"

namespace rekon {
namespace {

uint64_t fnv1a(const cv::Mat& m, uint64_t h) {
  for (int r = 0; r < m.rows; ++r) h = fnv1a64(m.ptr<uint8_t>(r), static_cast<size_t>(m.cols) * m.elemSize(), h);
  return h;
}

}  // namespace

uint64_t frameHash(const RgbdFrame& frame) { return fnv1a(frame.color, fnv1a(frame.depth, kFnv1aOffset)); }

}  // namespace rekon
