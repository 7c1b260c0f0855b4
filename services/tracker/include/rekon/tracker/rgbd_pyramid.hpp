#pragma once
// An RGB-D frame as the dense aligner reads it: per pyramid level a float
// intensity plane (0..1) and a float depth plane (metres, NaN = missing),
// structure of arrays, row-major. Level l halves the resolution l times.
#include <cstdint>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/rgbd_frame.hpp"

namespace rekon::tracker {

struct PyramidLevel {
  Intrinsics k;  // intrinsics of this level (k.width x k.height)
  std::vector<float> intensity;
  std::vector<float> depth;
  bool empty() const { return intensity.empty(); }
};

class RgbdPyramid {
 public:
  // Builds levels finest..coarsest from `frame` (levels finer than `finest`
  // are not stored). Reuses its buffers, so a pyramid rebuilt for frames of
  // one size allocates nothing. Depth outside [min_depth, max_depth] is
  // missing. Throws rekon::Error for a frame whose type or size does not
  // match `k`.
  void build(const RgbdFrame& frame, const Intrinsics& k, int finest, int coarsest, double min_depth,
             double max_depth);

  // Levels finest..coarsest from a stored finest level (a session's keyframe,
  // keyframe_archive.hpp) of the camera `k`. rekon::Error when the planes'
  // size is not k.atLevel(finest)'s or the levels do not fit the image.
  void restore(const Intrinsics& k, int finest, int coarsest, std::vector<float> intensity, std::vector<float> depth);

  // The full-resolution camera the pyramid was built or restored for.
  const Intrinsics& camera() const { return levels_.front().k; }
  int finestLevel() const { return finest_; }
  int coarsestLevel() const { return coarsest_; }
  bool hasLevel(int level) const { return level >= finest_ && level <= coarsest_ && !levels_[level].empty(); }
  const PyramidLevel& level(int level) const;

  // Measured on the full-resolution input while building.
  double validDepthFraction() const { return valid_depth_fraction_; }
  double meanIntensity() const { return mean_intensity_; }

 private:
  // Sizes levels 0..coarsest for `k` and frees those finer than `finest`.
  void setLevels(const Intrinsics& k, int finest, int coarsest);

  std::vector<PyramidLevel> levels_;
  std::vector<uint16_t> column_sums_;  // build()'s scratch: a row pair's color sums
  int finest_ = 0, coarsest_ = -1;
  double valid_depth_fraction_ = 0.0, mean_intensity_ = 0.0;
};

}  // namespace rekon::tracker
