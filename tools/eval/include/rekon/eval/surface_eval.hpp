#pragma once
// Surface accuracy as in the paper's Section 5: CORR, the mean distance from
// each vertex of a reconstructed mesh to the reference surface, and COMPL, the
// mean distance from points sampled uniformly on the reference surface to the
// reconstruction. Distances are exact point-to-triangle distances (to points
// when a mesh has no triangles) and capped, so a few far outliers or missing
// regions count as the cap instead of dominating the mean.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "rekon/common/mesh.hpp"

namespace rekon::eval {

struct SurfaceEvalOptions {
  // 5 cm: the top of the error scale of the paper's Figure 6.
  static constexpr double kDefaultCapM = 0.05;
  // Reference samples for COMPL: one per square centimetre of reference surface, within these bounds.
  static constexpr double kDefaultSamplesPerM2 = 1e4;
  static constexpr size_t kMinSamples = 10000;
  static constexpr size_t kMaxSamples = 2000000;
  double cap_m = kDefaultCapM;
  size_t reference_samples = 0;  // 0 = from the reference area as above
  uint64_t seed = 1;
  int threads = 0;  // 0 = every hardware thread
};

struct SurfaceErrors {
  double corr_m = 0.0;   // mean capped distance, mesh vertices -> reference
  double compl_m = 0.0;  // mean capped distance, reference samples -> mesh
  double corr_within_1cm = 0.0, corr_within_2cm = 0.0;  // fractions of vertices
  double compl_within_1cm = 0.0, compl_within_2cm = 0.0;
  double corr_median_m = 0.0, compl_median_m = 0.0;
  size_t mesh_vertices = 0;
  size_t reference_samples = 0;
  double cap_m = 0.0;
};

// Distance from each point to the surface (to its points when it has no
// triangles), at most cap_m; e.g. for coloring a reconstruction by its error.
std::vector<float> distancesToSurface(const std::vector<Eigen::Vector3f>& points, const Mesh& surface, double cap_m,
                                      int threads = 0);

// Throws rekon::Error when either mesh is empty.
SurfaceErrors evaluateSurface(const Mesh& mesh, const Mesh& reference, const SurfaceEvalOptions& options = {});

}  // namespace rekon::eval
