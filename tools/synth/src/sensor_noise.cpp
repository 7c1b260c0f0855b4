#include "sensor_noise.hpp"

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <numbers>

namespace rekon::synth {
namespace {

uint16_t toRaw(double z, double depth_scale) {
  const double raw = std::round(z * depth_scale);
  return (raw >= 1.0 && raw <= 65535.0) ? static_cast<uint16_t>(raw) : 0;
}

double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}

}  // namespace

double Rng::normal() {
  const double u1 = std::max(uniform(), 1e-300), u2 = uniform();
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * std::numbers::pi * u2);
}

namespace {
constexpr int kNormalTableBits = 12;
struct NormalTable {
  float v[1 << kNormalTableBits];
  NormalTable() {
    const int n = 1 << kNormalTableBits;
    for (int i = 0; i < n; ++i) {
      const double p = (i + 0.5) / n;
      double lo = -8.0, hi = 8.0;  // bisection on the normal CDF
      for (int it = 0; it < 60; ++it) {
        const double mid = 0.5 * (lo + hi);
        (0.5 * std::erfc(-mid / std::numbers::sqrt2) < p ? lo : hi) = mid;
      }
      v[i] = static_cast<float>(0.5 * (lo + hi));
    }
  }
};
const NormalTable kNormalTable;
}  // namespace

float Rng::fastNormal() { return kNormalTable.v[next() >> (64 - kNormalTableBits)]; }

uint64_t mixSeed(uint64_t a, uint64_t b) {
  Rng r(a * 0xD1B54A32D192ED03ull ^ (b + 0x8CB92BA72F3D8DD7ull));
  return r.next();
}

cv::Mat exactDepth(const RayCastImage& image, double depth_scale) {
  cv::Mat depth(image.height, image.width, CV_16UC1);
  for (int y = 0; y < image.height; ++y) {
    auto* row = depth.ptr<uint16_t>(y);
    for (int x = 0; x < image.width; ++x) row[x] = toRaw(image.depth[static_cast<size_t>(y) * image.width + x], depth_scale);
  }
  return depth;
}

cv::Mat exactColor(const RayCastImage& image) {
  cv::Mat color;
  image.color.convertTo(color, CV_8UC3, 255.0);
  return color;
}

cv::Mat kinectDepth(const RayCastImage& image, double depth_scale, uint64_t seed, int threads) {
  using M = KinectModel;
  const int w = image.width, h = image.height;
  cv::Mat depth(h, w, CV_16UC1);
  const double cos_start = std::cos(M::kGrazingStartDeg * std::numbers::pi / 180.0);
  const double cos_end = std::cos(M::kGrazingEndDeg * std::numbers::pi / 180.0);
  const double disparity_k = M::kBaselineM * M::kIrFocalPx;
  parallelRows(h, threads, [&](int y) {
    Rng rng(mixSeed(seed, static_cast<uint64_t>(y)));
    auto* row = depth.ptr<uint16_t>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const double z = image.depth[i];
      // Draw every random number of the pixel up front so that each pixel
      // consumes the same amount of the stream whatever the outcome.
      const double u_grazing = rng.uniform(), u_edge = rng.uniform(), u_speckle = rng.uniform(), n = rng.fastNormal();
      row[x] = 0;
      if (z < M::kMinDepthM || z > M::kMaxDepthM) continue;
      if (u_grazing < 1.0 - smoothstep(cos_end, cos_start, image.cos_incidence[i])) continue;
      if (u_speckle < M::kSpeckleDropProbability) continue;
      const double tau = M::kDiscontinuityRelative * z + M::kDiscontinuityAbsoluteM;
      bool behind_edge = false, before_edge = false;
      for (int dy = -1; dy <= 1; ++dy) {
        const int yy = y + dy;
        if (yy < 0 || yy >= h) continue;
        for (int dx = -2; dx <= 2; ++dx) {
          const int xx = x + dx;
          if (xx < 0 || xx >= w) continue;
          const double zn = image.depth[static_cast<size_t>(yy) * w + xx];
          if (zn <= 0.0 || zn - z > tau) before_edge = true;
          if (zn > 0.0 && z - zn > tau) behind_edge = true;
        }
      }
      if (behind_edge && u_edge < M::kShadowDropProbability) continue;
      if (!behind_edge && before_edge && u_edge < M::kEdgeDropProbability) continue;
      const double sigma = M::kSigmaBaseM + M::kSigmaQuadraticPerM * (z - 0.4) * (z - 0.4);
      const double noisy = std::max(z + sigma * n, 0.05);
      const double disparity = std::round(disparity_k / noisy * M::kDisparitySubpixels) / M::kDisparitySubpixels;
      if (disparity <= 0.0) continue;
      row[x] = toRaw(disparity_k / disparity, depth_scale);
    }
  });
  return depth;
}

cv::Mat kinectColor(const RayCastImage& image, uint64_t seed, int threads) {
  using M = KinectModel;
  cv::Mat blurred;
  cv::GaussianBlur(image.color, blurred, cv::Size(5, 5), M::kColorBlurSigmaPx);
  cv::Mat color(image.height, image.width, CV_8UC3);
  parallelRows(image.height, threads, [&](int y) {
    Rng rng(mixSeed(seed ^ 0xC0104ull, static_cast<uint64_t>(y)));
    const auto* in = blurred.ptr<cv::Vec3f>(y);
    auto* out = color.ptr<cv::Vec3b>(y);
    for (int x = 0; x < image.width; ++x) {
      for (int c = 0; c < 3; ++c) {
        const float v = 255.0f * (in[x][c] + static_cast<float>(M::kColorNoiseSigma) * rng.fastNormal()) + 0.5f;
        out[x][c] = static_cast<uint8_t>(std::clamp(v, 0.0f, 255.0f));
      }
    }
  });
  return color;
}

}  // namespace rekon::synth
