// `rekon synth`: writes a synthetic RGB-D sequence with exact ground truth.
#include <cmath>
#include <iostream>
#include <sstream>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/json.hpp"
#include "rekon/synth/synth.hpp"

namespace rekon::synth {
namespace {

// rekon synth --describe: what a scene is, measured on it (no frames written).
int describeScene(const SequenceOptions& o, double voxel_m, double truncation_m) {
  if (!(voxel_m >= 0.002 && voxel_m <= 0.5)) throw Error("--voxel must lie in [0.002, 0.5] m");
  if (!(truncation_m >= 0 && truncation_m <= 1)) throw Error("--truncation must lie in [0, 1] m");
  const auto scene = Scene::make(o.scene);
  const int frames = o.frames > 0 ? o.frames : scene->defaultFrames(o.laps);
  const Trajectory trajectory = scene->trajectory(frames, o.seed, o.laps);
  double path_m = 0;
  for (size_t i = 1; i < trajectory.size(); ++i) path_m += translationDistance(trajectory[i - 1].pose, trajectory[i].pose);
  const Mesh mesh = scene->groundTruthMesh();
  Eigen::Vector3f lo = mesh.vertices.front(), hi = lo;
  double area = 0;
  for (const auto& v : mesh.vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  for (const auto& t : mesh.triangles) {
    const auto& a = mesh.vertices[static_cast<size_t>(t[0])];
    area += 0.5 * (mesh.vertices[static_cast<size_t>(t[1])] - a).cross(mesh.vertices[static_cast<size_t>(t[2])] - a).norm();
  }
  BandOptions band{voxel_m, truncation_m, 8, 1e9};
  const int64_t all = surfaceBandBlocks(mesh, band);
  band.max_z_m = hi.z() - 0.05;  // the ceiling's triangles left out
  const int64_t below = surfaceBandBlocks(mesh, band);
  const double block_mib = 512.0 * 12.0 / (1024.0 * 1024.0);
  std::cout << o.scene << ": " << hi.x() - lo.x() << " x " << hi.y() - lo.y() << " x " << hi.z() - lo.z()
            << " m; path " << path_m << " m in " << frames << " frames (" << frames / 1800.0 << " min)\n";
  std::cout << keyValueLine({{"size_x_m", static_cast<double>(hi.x() - lo.x())},
                             {"size_y_m", static_cast<double>(hi.y() - lo.y())},
                             {"frames", frames},
                             {"path_m", path_m},
                             {"surface_m2", area},
                             {"mesh_vertices", static_cast<double>(mesh.vertices.size())},
                             {"voxel_m", voxel_m},
                             {"blocks", static_cast<double>(all)},
                             {"map_mib", static_cast<double>(all) * block_mib},
                             {"blocks_without_ceiling", static_cast<double>(below)},
                             {"map_mib_without_ceiling", static_cast<double>(below) * block_mib}})
            << "\n";
  return 0;
}

}  // namespace

int synthCommand(int argc, char** argv) {
  ArgParser args(argv[0], "Write a synthetic RGB-D sequence (TUM layout) with exact trajectory and colored mesh_gt.ply.");
  args.option("scene", "room, corridor, tabletop or building", "room")
      .option("out", "output folder (created)")
      .option("frames", "number of frames (0 = the scene's default for --laps)", "0")
      .option("minutes", "instead of --frames: this many minutes at 30 Hz (building: up to 60, 108,000 frames)", "0")
      .option("laps", "corridor: times round the out-and-back path (each lap after the first adds 5484 frames); "
                      "building: laps walked (A, B, C in turn; one lap is 11678 frames)", "1")
      .flag("describe", "print the scene's size, path, mesh and voxel map size (--voxel) instead of writing frames")
      .option("voxel", "with --describe: voxel size in metres for the map size (8^3-voxel blocks, 12 bytes a voxel)", "0.01")
      .option("truncation", "with --describe: truncation band in metres", "0.04")
      .option("seed", "seed of trajectory shake and sensor noise", "1")
      .option("noise", "kinect or none", "kinect")
      .option("jpeg", "color as JPEG of this quality (1-100) instead of PNG (a fifth of the bytes), for a long scan's "
                      "cache played by rekon bench longrun --dataset (0 = PNG)", "0")
      .option("drift", "T_PER_M,R_DEG_PER_M: also write drifted_trajectory.txt", "")
      .examples("rekon synth --scene room --out out/room\n"
                "rekon synth --scene corridor --laps 2 --out out/corridor2\n"
                "rekon synth --scene building --describe --minutes 60   # size, path, voxel map at 1 cm\n"
                "rekon synth --scene building --minutes 60 --jpeg 95 --out out/building60   # the hour as a cache\n"
                "rekon synth --scene room --frames 60 --drift 0.05,3 --out out/drifted   # with drifted_trajectory.txt");
  if (!args.parse(argc, argv)) return 0;
  const bool describe = args.flagSet("describe");
  if (!describe && !args.has("out")) throw Error("missing --out DIR; see " + std::string(argv[0]) + " --help");
  SequenceOptions o;
  o.scene = args.get("scene");
  o.frames = args.getInt("frames");
  const double minutes = args.getDouble("minutes");
  if (minutes != 0 && o.frames != 0) throw Error("give --frames or --minutes, not both");
  if (!(minutes >= 0 && minutes <= 600)) throw Error("--minutes " + args.get("minutes") + " must lie in [0, 600]");
  if (minutes > 0) o.frames = static_cast<int>(std::lround(minutes * 60.0 * 30.0));
  o.laps = args.getInt("laps");
  const std::string seed_text = args.get("seed");
  try {
    size_t used = 0;
    o.seed = std::stoull(seed_text, &used);
    if (used != seed_text.size()) throw std::invalid_argument("trailing");
  } catch (const std::exception&) {
    throw Error("--seed '" + seed_text + "' is not a non-negative integer");
  }
  o.noise = parseNoise(args.get("noise"));
  o.jpeg_quality = args.getInt("jpeg");
  if (!args.get("drift").empty()) {
    std::istringstream ss(args.get("drift"));
    char comma = 0;
    if (!(ss >> o.drift_translation_per_m >> comma >> o.drift_rotation_deg_per_m) || comma != ',' || !ss.eof()) {
      throw Error("--drift '" + args.get("drift") + "' must be T_PER_M,R_DEG_PER_M, e.g. 0.01,0.5");
    }
  }
  if (describe) return describeScene(o, args.getDouble("voxel"), args.getDouble("truncation"));
  const std::string out = args.get("out");
  const SequenceReport r = writeSequenceShowingProgress(o, out);
  std::cout << "wrote " << r.frames << " frames of " << o.scene << " to " << out << " in " << r.seconds << " s\n";
  std::cout << keyValueLine({{"frames", r.frames},
                             {"seconds", r.seconds},
                             {"frames_per_second", r.seconds > 0 ? r.frames / r.seconds : 0.0},
                             {"mesh_vertices", static_cast<double>(r.mesh_vertices)}})
            << "\n";
  return 0;
}

}  // namespace rekon::synth
