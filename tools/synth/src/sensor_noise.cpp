#include "sensor_noise.hpp"

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <numbers>

namespace rekon::synth {
namespace {

uint16_t toRaw(float z, float depth_scale) {
  const float raw = z * depth_scale + 0.5f;  // round to nearest; z >= 0
  return (raw >= 1.0f && raw < 65535.5f) ? static_cast<uint16_t>(raw) : 0;
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
  const float scale = static_cast<float>(depth_scale);
  for (int y = 0; y < image.height; ++y) {
    auto* row = depth.ptr<uint16_t>(y);
    for (int x = 0; x < image.width; ++x) row[x] = toRaw(image.depth[static_cast<size_t>(y) * image.width + x], scale);
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
  // Nearest and farthest depth around each pixel (5 x 3 window, the
  // projector's baseline is horizontal); pixels without depth count as far.
  constexpr float kFar = 1e9f;
  cv::Mat z(h, w, CV_32FC1, const_cast<float*>(image.depth.data()));
  cv::Mat z_or_far = z.clone();
  z_or_far.setTo(kFar, z <= 0.0f);
  cv::Mat nearest, farthest;
  const cv::Mat window = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(5, 3));
  cv::erode(z_or_far, nearest, window, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);
  cv::dilate(z_or_far, farthest, window, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);

  cv::Mat depth(h, w, CV_16UC1);
  const float cos_start = static_cast<float>(std::cos(M::kGrazingStartDeg * std::numbers::pi / 180.0));
  const float cos_end = static_cast<float>(std::cos(M::kGrazingEndDeg * std::numbers::pi / 180.0));
  const float disparity_k = static_cast<float>(M::kBaselineM * M::kIrFocalPx);
  const float subpixels = static_cast<float>(M::kDisparitySubpixels);
  const float scale = static_cast<float>(depth_scale);
  constexpr float kUnit16 = 1.0f / 65536.0f;
  parallelRows(h, threads, [&](int y) {
    Rng rng(mixSeed(seed, static_cast<uint64_t>(y)));
    const float* zr = z.ptr<float>(y);
    const float* near_r = nearest.ptr<float>(y);
    const float* far_r = farthest.ptr<float>(y);
    const float* cos_r = image.cos_incidence.data() + static_cast<size_t>(y) * w;
    auto* row = depth.ptr<uint16_t>(y);
    for (int x = 0; x < w; ++x) {
      // Every pixel consumes the same two draws, whatever happens to it, so
      // the noise of a pixel does not depend on its neighbours' fate.
      const uint64_t bits = rng.next();
      const float n = rng.fastNormal();
      const float u_grazing = static_cast<float>(bits & 0xFFFF) * kUnit16;
      const float u_edge = static_cast<float>((bits >> 16) & 0xFFFF) * kUnit16;
      const float u_speckle = static_cast<float>((bits >> 32) & 0xFFFF) * kUnit16;
      const float zc = zr[x];
      row[x] = 0;
      if (zc < M::kMinDepthM || zc > M::kMaxDepthM) continue;
      const float t = std::clamp((cos_r[x] - cos_end) / (cos_start - cos_end), 0.0f, 1.0f);
      if (u_grazing >= t * t * (3.0f - 2.0f * t)) continue;  // keep with probability smoothstep
      if (u_speckle < M::kSpeckleDropProbability) continue;
      const float tau = static_cast<float>(M::kDiscontinuityRelative) * zc + static_cast<float>(M::kDiscontinuityAbsoluteM);
      const bool behind_edge = zc - near_r[x] > tau;
      const bool before_edge = far_r[x] - zc > tau;
      if (behind_edge && u_edge < M::kShadowDropProbability) continue;
      if (!behind_edge && before_edge && u_edge < M::kEdgeDropProbability) continue;
      const float sigma = static_cast<float>(M::kSigmaBaseM) +
                          static_cast<float>(M::kSigmaQuadraticPerM) * (zc - 0.4f) * (zc - 0.4f);
      const float noisy = std::max(zc + sigma * n, 0.05f);
      const float disparity = static_cast<float>(static_cast<int32_t>(disparity_k / noisy * subpixels + 0.5f)) / subpixels;
      if (disparity <= 0.0f) continue;
      const float raw = disparity_k / disparity * scale + 0.5f;
      row[x] = raw >= 1.0f && raw < 65535.5f ? static_cast<uint16_t>(raw) : 0;
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
