// rekon_mesh_to_reference_frame MESH EST_TRAJ REF_TRAJ OUT: the tracker's world
// is its first camera; this moves a mesh built in it into the reference
// trajectory's world (T_ref(0) * T_est(0)^-1 at the first common timestamp) so
// that `rekon eval surface` can compare it with mesh_gt.ply.
#include <spdlog/spdlog.h>

#include <cstdio>

#include "rekon/common/error.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/eval/trajectory_eval.hpp"

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s MESH EST_TRAJ REF_TRAJ OUT\n", argv[0]);
    return 2;
  }
  try {
    const rekon::Trajectory est = rekon::readTumTrajectory(argv[2]), ref = rekon::readTumTrajectory(argv[3]);
    if (est.empty()) throw rekon::Error(std::string(argv[2]) + " is empty");
    const auto alignment = rekon::eval::firstPoseAlignment(est, ref);
    if (!alignment) throw rekon::Error(std::string(argv[3]) + " has no pose at the estimate's first timestamp");
    const Eigen::Isometry3f t = alignment->cast<float>();
    rekon::Mesh mesh = rekon::readPly(argv[1]);
    for (auto& v : mesh.vertices) v = t * v;
    rekon::writePly(mesh, argv[4]);
    spdlog::info("moved {} vertices into the reference frame: {}", mesh.vertices.size(), argv[4]);
  } catch (...) {
    spdlog::error("{}", rekon::currentExceptionLine());
    return 1;
  }
  return 0;
}
