#pragma once
// Turning an exact ray-cast image into what a sensor delivers: 16-bit depth
// and 8-bit color, exact or with Kinect-like (structured light) noise.
#include <opencv2/core/mat.hpp>

#include <cstdint>

#include "raycast.hpp"

namespace rekon::synth {

// Kinect v1 model. Depth: axial noise sigma_z = 0.0012 + 0.0019 (z - 0.4)^2
// (Nguyen et al. 2012, as DVO uses it), disparity quantised to 1/8 pixel with
// baseline 7.5 cm and IR focal length 580 px (step 2.9 mm at 1 m, 4.6 cm at
// 4 m, matching Smisek et al. 2011), no depth outside [0.4 m, 4 m], at grazing
// incidence, in the projector shadow behind depth discontinuities and at
// random speckles. Color: mild Gaussian blur and sensor noise.
struct KinectModel {
  static constexpr double kMinDepthM = 0.4;
  static constexpr double kMaxDepthM = 4.0;
  static constexpr double kSigmaBaseM = 0.0012;
  static constexpr double kSigmaQuadraticPerM = 0.0019;
  static constexpr double kBaselineM = 0.075;
  static constexpr double kIrFocalPx = 580.0;
  static constexpr double kDisparitySubpixels = 8.0;
  // Incidence angles: depth starts to drop out at 70 degrees and is gone at 85.
  static constexpr double kGrazingStartDeg = 70.0;
  static constexpr double kGrazingEndDeg = 85.0;
  // A neighbour nearer by more than this (relative to depth, plus a constant)
  // marks a discontinuity; the far side is in the projector's shadow.
  static constexpr double kDiscontinuityRelative = 0.05;
  static constexpr double kDiscontinuityAbsoluteM = 0.02;
  static constexpr double kShadowDropProbability = 0.8;
  static constexpr double kEdgeDropProbability = 0.2;
  static constexpr double kSpeckleDropProbability = 0.002;
  static constexpr double kColorBlurSigmaPx = 0.7;
  static constexpr double kColorNoiseSigma = 2.5 / 255.0;
};

cv::Mat exactDepth(const RayCastImage& image, double depth_scale);
cv::Mat exactColor(const RayCastImage& image);
cv::Mat kinectDepth(const RayCastImage& image, double depth_scale, uint64_t seed, int threads);
cv::Mat kinectColor(const RayCastImage& image, uint64_t seed, int threads);

// A small, fast, seedable generator (splitmix64), one stream per row so that
// results do not depend on the thread count.
struct Rng {
  uint64_t state;
  explicit Rng(uint64_t seed) : state(seed) {}
  uint64_t next() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double uniform() { return static_cast<double>(next() >> 11) * (1.0 / 9007199254740992.0); }
  // Standard normal by Box-Muller.
  double normal();
  // Standard normal from a 4096-entry inverse-CDF table: plenty for sensor
  // noise and several times faster.
  float fastNormal();
};

uint64_t mixSeed(uint64_t a, uint64_t b);

}  // namespace rekon::synth
