#pragma once
// Ray casting of a SceneModel into an exact depth map (camera z, metres), the
// incidence of each ray on the surface it hits, and a shaded color image.
#include <opencv2/core/mat.hpp>

#include <functional>
#include <vector>

#include "geometry.hpp"
#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"
#include "texture.hpp"

namespace rekon::synth {

struct RayCastImage {
  int width = 0, height = 0;
  std::vector<float> depth;          // camera z in metres; 0 = nothing hit
  std::vector<float> cos_incidence;  // |cos| of the angle between ray and surface normal
  cv::Mat color;                     // CV_32FC3, BGR in [0, 1]
};

// `threads` workers split the rows. Object edges are anti-aliased in color by
// 2x2 supersampling of the pixels where the hit surface changes.
RayCastImage rayCast(const SceneModel& scene, const std::vector<Material>& materials, const Intrinsics& k,
                     const Pose& camera_to_world, int threads);

// Runs body(row) for every row on `threads` workers (rows handed out in chunks).
void parallelRows(int rows, int threads, const std::function<void(int)>& body);

}  // namespace rekon::synth
