#include "rekon/tracker/rgbd_pyramid.hpp"

#include <cmath>
#include <limits>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/common/simd.hpp"

namespace rekon::tracker {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
// ITU-R BT.601 luma of 8-bit values, scaled to 0..1.
constexpr float kWr = 0.299f / 255.f, kWg = 0.587f / 255.f, kWb = 0.114f / 255.f;

void checkFrame(const RgbdFrame& frame, const Intrinsics& k) {
  const std::string what = "frame " + std::to_string(frame.id);
  if (frame.depth.type() != CV_16UC1)
    throw Error(what + ": depth must be 16-bit single-channel (CV_16UC1); convert it before tracking");
  if (frame.color.type() != CV_8UC3)
    throw Error(what + ": color must be 8-bit BGR (CV_8UC3); convert it before tracking");
  if (frame.depth.cols != k.width || frame.depth.rows != k.height || frame.color.cols != k.width ||
      frame.color.rows != k.height)
    throw Error(what + ": image size differs from the camera's " + std::to_string(k.width) + "x" +
                std::to_string(k.height) + "; fix camera.yaml or the images");
}

// Mean of the valid depths of a 2x2 block; missing when fewer than two are
// valid or they straddle an occlusion edge (averaging would invent a surface).
// Branch-free, so that the loops calling it vectorise (the bounds as
// selectMin(lo, valid ? z : lo): GCC does not vectorise the select of a
// select): an invalid depth adds 0 and leaves the bounds as they are, the
// result a test per depth would give.
inline float blockDepth(float a, float b, float c, float d) {
  float sum = 0.f, lo = std::numeric_limits<float>::max(), hi = 0.f, n = 0.f;
  const auto add = [&](float z) {
    const bool valid = z == z;
    sum += valid ? z : 0.f;
    lo = selectMin(lo, valid ? z : lo);
    hi = selectMax(hi, valid ? z : hi);
    n += valid ? 1.f : 0.f;
  };
  add(a);
  add(b);
  add(c);
  add(d);
  return (n < 2.f) | (hi - lo > 0.1f * lo) ? kNaN : sum / n;
}

REKON_SIMD_CLONES void downsample(const PyramidLevel& src, PyramidLevel& dst) {
  const int w = dst.k.width, h = dst.k.height, sw = src.k.width;
  dst.intensity.resize(static_cast<size_t>(w) * h);
  dst.depth.resize(static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y) {
    const float* i0 = src.intensity.data() + static_cast<size_t>(2 * y) * sw;
    const float* i1 = i0 + sw;
    const float* d0 = src.depth.data() + static_cast<size_t>(2 * y) * sw;
    const float* d1 = d0 + sw;
    float* io = dst.intensity.data() + static_cast<size_t>(y) * w;
    float* dout = dst.depth.data() + static_cast<size_t>(y) * w;
    for (int x = 0; x < w; ++x) {
      io[x] = 0.25f * (i0[2 * x] + i0[2 * x + 1] + i1[2 * x] + i1[2 * x + 1]);
      dout[x] = blockDepth(d0[2 * x], d0[2 * x + 1], d1[2 * x], d1[2 * x + 1]);
    }
  }
}

struct DepthRange {
  float to_m, zmin, zmax;
  // Metres, NaN where the sensor gave none or the depth is out of range.
  float metres(uint16_t raw) const {
    const float z = static_cast<float>(raw) * to_m;
    return (raw == 0) | (z < zmin) | (z > zmax) ? kNaN : z;
  }
};

// What build() measures on the full-resolution input.
struct InputStats {
  long long valid = 0;  // pixels with a depth
  double intensity_sum = 0.0;
};

// One input row as level 0; returns the row's intensity sum.
inline float convertRow(const uint8_t* __restrict c, const uint16_t* __restrict d, int w, const DepthRange range,
                        float* __restrict io, float* __restrict dout, int& valid) {
  float row_sum = 0.f;
#pragma omp simd reduction(+ : row_sum)
  for (int x = 0; x < w; ++x) {
    io[x] = kWb * c[3 * x] + kWg * c[3 * x + 1] + kWr * c[3 * x + 2];
    row_sum += io[x];
  }
  for (int x = 0; x < w; ++x) {
    dout[x] = range.metres(d[x]);
    valid += d[x] != 0;
  }
  return row_sum;
}

// The input as level 0 (tracker.finest_level 0; the default folds to level 1).
// The depth loop vectorises; GCC 12 leaves the 3-byte color loop of the AVX2
// clone scalar.
REKON_SIMD_CLONES InputStats convertFull(const RgbdFrame& frame, const DepthRange range, PyramidLevel& l0) {
  const int w = l0.k.width, h = l0.k.height;
  l0.intensity.resize(static_cast<size_t>(w) * h);
  l0.depth.resize(static_cast<size_t>(w) * h);
  InputStats stats;
  for (int y = 0; y < h; ++y) {
    int valid = 0;
    stats.intensity_sum += convertRow(frame.color.ptr<uint8_t>(y), frame.depth.ptr<uint16_t>(y), w, range,
                                      l0.intensity.data() + static_cast<size_t>(y) * w,
                                      l0.depth.data() + static_cast<size_t>(y) * w, valid);
    stats.valid += valid;
  }
  return stats;
}

// The input folded into level 1: 2x2 blocks, intensity the mean of the block's
// colors' luma, depth blockDepth() of its depths. The colors in two passes,
// each of which vectorises (the 6-byte stride of a block's colors does not):
// the row pair's sums per channel as planes in `column_sums`, then the
// horizontal pairs.
REKON_SIMD_CLONES InputStats foldToHalf(const RgbdFrame& frame, const DepthRange range, PyramidLevel& l1,
                                        std::vector<uint16_t>& column_sums) {
  const int w1 = l1.k.width, h1 = l1.k.height, w = 2 * w1;
  l1.intensity.resize(static_cast<size_t>(w1) * h1);
  l1.depth.resize(static_cast<size_t>(w1) * h1);
  column_sums.resize(3 * static_cast<size_t>(w));
  uint16_t* __restrict sb = column_sums.data();
  uint16_t* __restrict sg = sb + w;
  uint16_t* __restrict sr = sg + w;
  InputStats stats;
  for (int y = 0; y < h1; ++y) {
    const uint8_t* __restrict c0 = frame.color.ptr<uint8_t>(2 * y);
    const uint8_t* __restrict c1 = frame.color.ptr<uint8_t>(2 * y + 1);
    for (int x = 0; x < w; ++x) {
      sb[x] = static_cast<uint16_t>(c0[3 * x] + c1[3 * x]);
      sg[x] = static_cast<uint16_t>(c0[3 * x + 1] + c1[3 * x + 1]);
      sr[x] = static_cast<uint16_t>(c0[3 * x + 2] + c1[3 * x + 2]);
    }
    const uint16_t* __restrict d0 = frame.depth.ptr<uint16_t>(2 * y);
    const uint16_t* __restrict d1 = frame.depth.ptr<uint16_t>(2 * y + 1);
    float* __restrict io = l1.intensity.data() + static_cast<size_t>(y) * w1;
    float* __restrict dout = l1.depth.data() + static_cast<size_t>(y) * w1;
    float row_sum = 0.f;
    int valid = 0;
#pragma omp simd reduction(+ : row_sum, valid)
    for (int x = 0; x < w1; ++x) {
      const int b = sb[2 * x] + sb[2 * x + 1], g = sg[2 * x] + sg[2 * x + 1], r = sr[2 * x] + sr[2 * x + 1];
      io[x] = 0.25f * (kWb * static_cast<float>(b) + kWg * static_cast<float>(g) + kWr * static_cast<float>(r));
      row_sum += io[x];
      const uint16_t r00 = d0[2 * x], r01 = d0[2 * x + 1], r10 = d1[2 * x], r11 = d1[2 * x + 1];
      valid += (r00 != 0) + (r01 != 0) + (r10 != 0) + (r11 != 0);
      dout[x] = blockDepth(range.metres(r00), range.metres(r01), range.metres(r10), range.metres(r11));
    }
    stats.intensity_sum += row_sum;
    stats.valid += valid;
  }
  stats.intensity_sum *= 4.0;  // each level-1 pixel stands for four input pixels
  return stats;
}

}  // namespace

const PyramidLevel& RgbdPyramid::level(int l) const {
  if (!hasLevel(l))
    throw Error("pyramid level " + std::to_string(l) + " was not built (levels " + std::to_string(finest_) + ".." +
                std::to_string(coarsest_) + "); build the pyramid with the levels the aligner uses");
  return levels_[l];
}

void RgbdPyramid::setLevels(const Intrinsics& k, int finest, int coarsest) {
  if (finest < 0 || coarsest < finest || (k.width >> coarsest) < 8 || (k.height >> coarsest) < 8)
    throw Error("pyramid levels " + std::to_string(finest) + ".." + std::to_string(coarsest) +
                " do not fit a " + std::to_string(k.width) + "x" + std::to_string(k.height) +
                " image; use 0 <= finest <= coarsest with at least 8x8 pixels at the coarsest");
  finest_ = finest;
  coarsest_ = coarsest;
  if (static_cast<int>(levels_.size()) < coarsest + 1) levels_.resize(coarsest + 1);
  for (int l = 0; l <= coarsest; ++l) levels_[l].k = k.atLevel(l);
  for (int l = 0; l < finest; ++l) {
    levels_[l].intensity.clear();
    levels_[l].depth.clear();
  }
}

void RgbdPyramid::restore(const Intrinsics& k, int finest, int coarsest, std::vector<float> intensity,
                          std::vector<float> depth) {
  setLevels(k, finest, coarsest);
  PyramidLevel& l = levels_[finest];
  const size_t n = static_cast<size_t>(l.k.width) * static_cast<size_t>(l.k.height);
  if (intensity.size() != n || depth.size() != n)
    throw Error("stored pyramid level " + std::to_string(finest) + " holds " + std::to_string(intensity.size()) +
                " pixels, the camera's level has " + std::to_string(n));
  l.intensity = std::move(intensity);
  l.depth = std::move(depth);
  for (int c = finest + 1; c <= coarsest; ++c) downsample(levels_[c - 1], levels_[c]);
}

void RgbdPyramid::build(const RgbdFrame& frame, const Intrinsics& k, int finest, int coarsest, double min_depth,
                        double max_depth) {
  checkFrame(frame, k);
  setLevels(k, finest, coarsest);
  const DepthRange range{static_cast<float>(1.0 / k.depth_scale), static_cast<float>(min_depth),
                         static_cast<float>(max_depth)};
  // Full resolution: either stored as level 0, or folded straight into level 1
  // so that a 3 -> 1 pyramid never materialises the 640x480 planes.
  const InputStats stats = finest == 0 ? convertFull(frame, range, levels_[0]) : foldToHalf(frame, range, levels_[1], column_sums_);
  const double n = static_cast<double>(k.width) * k.height;
  valid_depth_fraction_ = static_cast<double>(stats.valid) / n;
  mean_intensity_ = stats.intensity_sum / n;
  for (int l = finest == 0 ? 1 : 2; l <= coarsest; ++l) downsample(levels_[l - 1], levels_[l]);
}

}  // namespace rekon::tracker
