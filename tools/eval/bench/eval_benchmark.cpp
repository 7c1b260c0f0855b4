// rekon_eval_benchmark [SPACING_M]: time of `evaluateSurface` for a mesh of
// about a million vertices (the room's ground truth at 1 cm, shifted by 5 mm)
// against the room's ground truth at its default spacing.
#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "rekon/common/error.hpp"
#include "rekon/eval/surface_eval.hpp"
#include "rekon/synth/synth.hpp"

int main(int argc, char** argv) try {
  const double spacing = argc > 1 ? std::atof(argv[1]) : 0.01;
  const auto scene = rekon::synth::Scene::make("room");
  const rekon::Mesh ref = scene->groundTruthMesh();
  rekon::Mesh mesh = scene->groundTruthMesh(spacing);
  for (auto& v : mesh.vertices) v.z() += 0.005f;
  const auto t0 = std::chrono::steady_clock::now();
  const auto e = rekon::eval::evaluateSurface(mesh, ref);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("mesh_vertices=%zu reference_triangles=%zu reference_samples=%zu corr_m=%.5f compl_m=%.5f seconds=%.2f\n",
              mesh.vertices.size(), ref.triangles.size(), e.reference_samples, e.corr_m, e.compl_m, s);
} catch (...) {
  std::fprintf(stderr, "rekon_eval_benchmark: %s\n", rekon::currentExceptionLine().c_str());
  return 1;
}
