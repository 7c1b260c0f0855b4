#pragma once
// Procedural, band-limited surface textures. Photometric tracking needs image
// gradients at every pyramid level, so each material mixes a checker, stripes
// and gradient noise at several octaves (periods from ~1 m down to ~1 cm).
// Every component is filtered by the footprint of the sample (a pixel or a
// mesh vertex spacing): edges are as sharp as the footprint allows and
// components finer than the footprint fade to their mean instead of aliasing.
#include <cstdint>

#include "geometry.hpp"

namespace rekon::synth {

struct Material {
  V3 color_a{0.1f, 0.1f, 0.1f};  // linear RGB in [0, 1], the two ends of the pattern
  V3 color_b{0.9f, 0.9f, 0.9f};
  float checker_period = 0.0f;  // metres; 0 = no checker
  float stripe_period = 0.0f;   // metres; 0 = no stripes
  float stripe_cos = 1.0f;      // direction of the stripe wave
  float stripe_sin = 0.0f;
  float checker_weight = 0.0f;
  float stripe_weight = 0.0f;
  float noise_weight = 0.6f;
  uint32_t seed = 1;
};

// Direction towards the (view-independent) light; shading must not depend on
// the viewpoint so that brightness constancy holds exactly between frames.
V3 lightDirection();

// Shaded color (RGB in [0, 1]) of the surface point as seen with a sample
// footprint of `footprint_m` metres.
V3 shade(const Material& m, const SurfacePoint& s, float footprint_m);

}  // namespace rekon::synth
