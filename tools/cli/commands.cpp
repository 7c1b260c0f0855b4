#include "commands.hpp"

#include "rekon/eval/eval_command.hpp"
#include "rekon/constrain/constrain.hpp"
#include "rekon/frontend_check/frontend_check.hpp"

#include "rekon/render/render.hpp"

#include "rekon/mapper_bench/bench_command.hpp"
#include "launcher.hpp"
#include "listen.hpp"
#include "rekon/report/run_report.hpp"

#include "rekon/synth/synth.hpp"

namespace rekon {

const std::vector<Command>& commands() {
  static const std::vector<Command> table = {
      {"eval", "trajectory (ATE, RPE) and surface (CORR, COMPL) errors against ground truth", &eval::evalCommand},
      {"render", "offscreen shaded image of a colored mesh (PLY to PNG)", &render::renderCommand},
      {"fuse", "integrate a dataset at given poses into the TSDF volume and write its mesh", &fuseCommand},
      {"odometry", "dense RGB-D odometry (DVO) in-process on a dataset; writes a TUM trajectory", &odometryCommand},
      {"synth", "write a synthetic RGB-D sequence with exact ground truth", &synth::synthCommand},
      {"run", "run the whole pipeline on a dataset or a live camera (every service as its own process)", &runCommand},
      {"cameras", "list the connected RGB-D cameras (OpenNI2, libfreenect, RealSense) and their modes", &camerasCommand},
      {"view", "serve a live web page of the run on the bus (mesh, camera, keyframes, status); prints its URL", &viewCommand},
      {"demo", "run the whole pipeline on the built-in default scene", &demoCommand},
      {"chaos", "run a dataset twice, the second time killing a random service every few seconds; compare the two",
       &chaosCommand},
      {"remesh", "rebuild a session's mesh at other settings (voxel size, truncation) without re-tracking", &remeshCommand},
      {"export", "write a session's trajectory (TUM), pose graph (g2o) and mesh (PLY)", &exportCommand},
      {"keyframes", "list or export the KF keyframes in the mapper's shared-memory keyframe store", &keyframesCommand},
      {"frontend-check", "judge a frontend's messages against messages/FRONTEND.md (live on the bus or an lcm-logger log)",
       &frontend_check::frontendCheckCommand},
      {"constrain", "send the optimiser an external loop edge or absolute pose prior (messages/external_constraint.lcm)",
       &constrain::constrainCommand},
      {"import", "a ROS 1 or ROS 2 bag (sqlite3, mcap) to a dataset folder: rekon import bag FILE --out DATASET", &importCommand},
      {"spy", "lcm-spy on the run's bus, every channel decoded with rekon's types", &spyCommand},
      {"listen", "a consumer on the bus: each frame's id, timestamp and hash, or with --mesh the mapper's mesh as a PLY", &listenMain},
      {"report", "self-contained report.html of a run folder: mesh views, trajectory, timing, stats", &report::reportCommand},
      {"bench", "mapper benchmarks: keyframes and reintegration (the paper's Figures 5 and 7), peers, scaling", &mapper_bench::benchCommand},
  };
  return table;
}

}  // namespace rekon
