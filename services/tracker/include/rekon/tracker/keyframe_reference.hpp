#pragma once
// The keyframe side of the dense alignment, computed once per keyframe: for
// every selected pixel of every level its 3D point, its intensity, and the
// Jacobians of the photometric and geometric residuals with respect to the
// inverse-compositional increment (Kerl et al. ICRA 2013; keyframe-side
// gradients, so an alignment iteration is one warp and one reduction).
#include <vector>

#include "rekon/tracker/params.hpp"
#include "rekon/tracker/rgbd_pyramid.hpp"

namespace rekon::tracker {

class KeyframeReference {
 public:
  // Per selected pixel kPointStride floats (x y z intensity). The Jacobians
  // as kJacobianRows planes of `count` floats (photometric J[0..5], then
  // geometric J[0..5]): an alignment reads every pixel's in order, so each
  // plane is a contiguous stream for vector loads.
  static constexpr int kPointStride = 4;
  static constexpr int kJacobianRows = 12;

  struct Level {
    Intrinsics k;
    int count = 0;
    std::vector<float> points;
    std::vector<float> jacobians;
  };

  KeyframeReference() = default;
  // Selects pixels with valid depth, no occlusion edge and enough intensity
  // gradient on levels params.finest_level..params.coarsest_level of `pyramid`.
  KeyframeReference(const RgbdPyramid& pyramid, const AlignerParams& params);

  int finestLevel() const { return finest_; }
  int coarsestLevel() const { return coarsest_; }
  bool hasLevel(int l) const { return l >= finest_ && l <= coarsest_; }
  const Level& level(int l) const;

 private:
  std::vector<Level> levels_;
  int finest_ = 0, coarsest_ = -1;
};

}  // namespace rekon::tracker
