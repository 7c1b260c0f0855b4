#include "texture.hpp"

#include <cmath>

namespace rekon::synth {
namespace {

// Noise octaves: periods in metres and relative amplitudes.
constexpr int kOctaves = 5;
constexpr float kOctavePeriod[kOctaves] = {0.9f, 0.31f, 0.11f, 0.038f, 0.013f};
constexpr float kOctaveAmplitude[kOctaves] = {0.55f, 0.5f, 0.45f, 0.4f, 0.35f};
// Ambient and directional parts of the Lambert shading.
constexpr float kAmbient = 0.6f;
constexpr float kDiffuse = 0.4f;

// floor() without a libm call on the x86-64 baseline (no SSE4.1 roundss).
inline float fastFloor(float x) {
  const float t = static_cast<float>(static_cast<int32_t>(x));
  return t > x ? t - 1.0f : t;
}

inline float smoothstep(float e0, float e1, float x) {
  const float t = std::clamp((x - e0) / (e1 - e0), 0.0f, 1.0f);
  return t * t * (3.0f - 2.0f * t);
}

// How much of a component with `period` survives a footprint: all of it at
// four samples per period, none at the Nyquist limit of two.
inline float keep(float period, float footprint) { return smoothstep(2.0f * footprint, 4.0f * footprint, period); }

// A square wave in [-1, 1] with edges blurred over about one footprint.
inline float squareWave(float x, float period, float footprint) {
  const float k = keep(period, footprint);
  if (k <= 0.0f) return 0.0f;
  float f = x / period;
  f -= fastFloor(f);
  const float tri = 1.0f - 4.0f * std::abs(f - 0.5f);
  return k * std::clamp(tri * period / (4.0f * footprint), -1.0f, 1.0f);
}

// Permutation table of the classic Perlin noise, widened to 1024 entries so
// the finest octave repeats only every ~13 m.
constexpr int kPermSize = 1024;
struct Permutation {
  uint16_t p[2 * kPermSize];
  Permutation() {
    uint32_t state = 0x1234567u;
    for (int i = 0; i < kPermSize; ++i) p[i] = static_cast<uint16_t>(i);
    for (int i = kPermSize - 1; i > 0; --i) {
      state = state * 1664525u + 1013904223u;
      const int j = static_cast<int>((state >> 8) % static_cast<uint32_t>(i + 1));
      std::swap(p[i], p[j]);
    }
    for (int i = 0; i < kPermSize; ++i) p[kPermSize + i] = p[i];
  }
};
const Permutation kPerm;

inline uint32_t hash(int32_t x, int32_t y, uint32_t seed) {
  const uint32_t xi = (static_cast<uint32_t>(x) + seed) & (kPermSize - 1);
  const uint32_t yi = static_cast<uint32_t>(y) & (kPermSize - 1);
  return kPerm.p[kPerm.p[xi] + yi];
}

// 2D gradient (Perlin) noise, roughly in [-1, 1].
inline float gradientNoise(float x, float y, uint32_t seed) {
  static const float gx[8] = {1.0f, -1.0f, 0.0f, 0.0f, 0.7071f, -0.7071f, 0.7071f, -0.7071f};
  static const float gy[8] = {0.0f, 0.0f, 1.0f, -1.0f, 0.7071f, 0.7071f, -0.7071f, -0.7071f};
  const float fx = fastFloor(x), fy = fastFloor(y);
  const int32_t ix = static_cast<int32_t>(fx), iy = static_cast<int32_t>(fy);
  const float rx = x - fx, ry = y - fy;
  auto corner = [&](int dx, int dy) {
    const uint32_t h = hash(ix + dx, iy + dy, seed) & 7u;
    return gx[h] * (rx - static_cast<float>(dx)) + gy[h] * (ry - static_cast<float>(dy));
  };
  const float sx = rx * rx * rx * (rx * (rx * 6.0f - 15.0f) + 10.0f);
  const float sy = ry * ry * ry * (ry * (ry * 6.0f - 15.0f) + 10.0f);
  const float a = corner(0, 0) + sx * (corner(1, 0) - corner(0, 0));
  const float b = corner(0, 1) + sx * (corner(1, 1) - corner(0, 1));
  return 1.4f * (a + sy * (b - a));
}

}  // namespace

V3 lightDirection() { return normalized(V3{0.35f, 0.25f, 0.9f}); }

V3 shade(const Material& m, const SurfacePoint& s, float footprint_m) {
  const float w = std::max(footprint_m, 1e-4f);
  float value = 0.0f;
  if (m.checker_period > 0.0f && m.checker_weight > 0.0f) {
    value += m.checker_weight * squareWave(s.u, m.checker_period, w) * squareWave(s.v, m.checker_period, w);
  }
  if (m.stripe_period > 0.0f && m.stripe_weight > 0.0f) {
    const float x = s.u * m.stripe_cos + s.v * m.stripe_sin;
    value += m.stripe_weight * squareWave(x, m.stripe_period, w);
  }
  if (m.noise_weight > 0.0f) {
    float n = 0.0f;
    for (int o = 0; o < kOctaves; ++o) {
      const float k = keep(kOctavePeriod[o], w);
      if (k <= 0.0f) continue;
      const float inv = 1.0f / kOctavePeriod[o];
      n += k * kOctaveAmplitude[o] * gradientNoise(s.u * inv, s.v * inv, m.seed + 211u * static_cast<uint32_t>(o));
    }
    value += m.noise_weight * n;
  }
  const float t = std::clamp(0.5f + 0.5f * value, 0.0f, 1.0f);
  V3 c = m.color_a + (m.color_b - m.color_a) * t;
  const float light = kAmbient + kDiffuse * std::max(0.0f, dot(s.normal, lightDirection()));
  c = c * light;
  return {std::clamp(c.x, 0.0f, 1.0f), std::clamp(c.y, 0.0f, 1.0f), std::clamp(c.z, 0.0f, 1.0f)};
}

}  // namespace rekon::synth
