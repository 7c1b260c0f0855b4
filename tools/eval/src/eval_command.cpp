// `rekon eval traj` and `rekon eval surface`: print the metrics, last line key=value (or JSON with --json).
#include <chrono>
#include <filesystem>
#include <optional>
#include <cstdio>
#include <iostream>
#include <string>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/json.hpp"
#include "rekon/eval/eval_command.hpp"
#include "rekon/eval/surface_eval.hpp"
#include "rekon/eval/trajectory_eval.hpp"

namespace rekon::eval {
namespace {

// The layout of every command's --help (ArgParser::usage): usage, summary, the two evaluations, examples.
constexpr const char* kUsage =
    "usage: rekon eval traj|surface ARGS [options]\n\n"
    "Trajectory and surface errors of a run against ground truth.\n\n"
    "commands:\n"
    "  traj GT EST         ATE (after rigid Horn/Umeyama alignment) and RPE per second of TUM trajectories\n"
    "  surface MESH REF    CORR (MESH vertices to REF's surface) and COMPL (REF's surface to MESH), capped; a run's\n"
    "                      mesh is moved into a dataset's world through the run's trajectory.txt and the dataset's\n"
    "                      groundtruth.txt, found beside MESH and REF when not given\n"
    "  (rekon eval traj --help and rekon eval surface --help list their options)\n\n"
    "examples:\n"
    "  rekon eval traj ../shared/data/7scenes_loop_1000/groundtruth.txt out/7scenes/trajectory.txt\n"
    "  rekon eval surface out/demo/mesh.ply out/demo/room_0_data/mesh_gt.ply\n"
    "  rekon eval surface out/a/mesh.ply out/b/mesh.ply      # two runs of one dataset: both in the first camera's frame\n";

// The trajectories that take MESH into REF's world: given, or found beside
// them (a run's trajectory.txt, a dataset's groundtruth.txt). None when REF is
// not in a dataset's world (another run's mesh) or --no-align says so; an
// error when REF is and MESH's trajectory cannot be found, because CORR and
// COMPL of two frames' meshes would be numbers about the frames, not the surface.
struct Alignment {
  std::string est, gt;
};

std::optional<Alignment> alignmentFor(const ArgParser& args) {
  namespace fs = std::filesystem;
  if (args.flagSet("no-align")) {
    if (!args.get("est-trajectory").empty()) throw Error("--no-align and --est-trajectory contradict each other; give one");
    return std::nullopt;
  }
  if (args.get("est-trajectory").empty() != args.get("gt-trajectory").empty())
    throw Error("--est-trajectory and --gt-trajectory go together; give both or neither");
  if (!args.get("est-trajectory").empty()) return Alignment{args.get("est-trajectory"), args.get("gt-trajectory")};
  const fs::path gt = fs::path(args.get("REF")).parent_path() / "groundtruth.txt";
  if (!fs::exists(gt)) return std::nullopt;  // REF is not in a dataset's world
  const fs::path est = fs::path(args.get("MESH")).parent_path() / "trajectory.txt";
  if (!fs::exists(est))
    throw Error(args.get("REF") + " is in its dataset's world (" + gt.string() + " beside it) and " + args.get("MESH") +
                " has no trajectory.txt beside it: give --est-trajectory (the run's trajectory.txt) --gt-trajectory " +
                gt.string() + ", or --no-align if MESH is already in REF's world");
  return Alignment{est.string(), gt.string()};
}

std::string fmt(double v, const char* f = "%.6f") {
  char buf[64];
  std::snprintf(buf, sizeof(buf), f, v);
  return buf;
}

int trajMain(int argc, char** argv) {
  ArgParser args("rekon eval traj", "Trajectory errors: ATE RMSE after rigid alignment, RPE per second.");
  args.positional("GT", "ground-truth TUM trajectory")
      .positional("EST", "estimated TUM trajectory")
      .option("max-dt", "largest timestamp difference of associated poses (s)",
              fmt(TrajectoryEvalOptions::kDefaultMaxTimeDifferenceS, "%g"))
      .option("delta", "RPE interval (s)", fmt(TrajectoryEvalOptions::kDefaultRpeDeltaS, "%g"))
      .option("offset", "seconds added to EST's timestamps before association (associate.py's --offset), e.g. -1 for a "
                        "fakenect recording of a dataset that starts at 0", "0")
      .flag("json", "print JSON instead of text")
      .examples("rekon eval traj ../shared/data/7scenes_loop_1000/groundtruth.txt out/7scenes/trajectory.txt\n"
                "rekon eval traj out/demo/room_0_data/groundtruth.txt out/demo/trajectory.txt --json");
  if (!args.parse(argc, argv)) return 0;
  TrajectoryEvalOptions o;
  o.max_time_difference_s = args.getDouble("max-dt");
  o.rpe_delta_s = args.getDouble("delta");
  o.time_offset_s = args.getDouble("offset");
  const Trajectory gt = readTumTrajectory(args.get("GT")), est = readTumTrajectory(args.get("EST"));
  const TrajectoryErrors e = evaluateTrajectory(gt, est, o);
  if (args.flagSet("json")) {
    JsonObject j;
    j.set("matched", e.matched)
        .set("estimated", est.size())
        .set("ate_rmse_m", e.ate_rmse_m)
        .set("ate_mean_m", e.ate_mean_m)
        .set("ate_median_m", e.ate_median_m)
        .set("ate_max_m", e.ate_max_m)
        .set("rpe_trans_m_per_s", e.rpe_trans_m_per_s)
        .set("rpe_rot_deg_per_s", e.rpe_rot_deg_per_s)
        .set("rpe_pairs", e.rpe_pairs)
        .set("rpe_delta_s", e.rpe_delta_s);
    std::cout << j.str() << "\n";
    return 0;
  }
  std::cout << "associated " << e.matched << " of " << est.size() << " estimated poses (within " << o.max_time_difference_s
            << " s)\n"
            << "ATE  rmse " << fmt(e.ate_rmse_m) << " m  mean " << fmt(e.ate_mean_m) << " m  median " << fmt(e.ate_median_m)
            << " m  max " << fmt(e.ate_max_m) << " m\n"
            << "RPE  " << fmt(e.rpe_trans_m_per_s) << " m/s  " << fmt(e.rpe_rot_deg_per_s, "%.4f") << " deg/s  (rmse over "
            << e.rpe_pairs << " pairs " << e.rpe_delta_s << " s apart)\n"
            << keyValueLine({{"ate_rmse_m", e.ate_rmse_m},
                             {"rpe_trans_m_per_s", e.rpe_trans_m_per_s},
                             {"rpe_rot_deg_per_s", e.rpe_rot_deg_per_s}})
            << "\n";
  return 0;
}

int surfaceMain(int argc, char** argv) {
  ArgParser args("rekon eval surface", "Surface errors of the paper's Section 5: CORR and COMPL (capped mean distances).");
  args.positional("MESH", "reconstructed mesh (PLY)")
      .positional("REF", "reference mesh (PLY), e.g. mesh_gt.ply of a synthetic sequence")
      .option("cap", "distances above this count as this (m)", fmt(SurfaceEvalOptions::kDefaultCapM, "%g"))
      .option("samples", "points sampled on REF for COMPL (0 = one per cm^2, 10k to 2M)", "0")
      .option("est-trajectory", "the TUM trajectory MESH was built with: MESH is first moved by the rigid alignment "
              "that maps it onto --gt-trajectory (the ATE's), so a SLAM mesh meets REF in REF's world", "")
      .option("gt-trajectory", "ground-truth TUM trajectory in REF's world (with --est-trajectory)", "")
      .flag("no-align", "compare MESH and REF as they are (both already in one frame); without it and without the "
                        "two trajectories, MESH's trajectory.txt and REF's groundtruth.txt are used when found")
      .flag("json", "print JSON instead of text")
      .examples("rekon eval surface out/demo/mesh.ply out/demo/room_0_data/mesh_gt.ply   # trajectories found beside them\n"
                "rekon eval surface MESH REF --est-trajectory EST --gt-trajectory GT\n"
                "rekon eval surface out/a/mesh.ply out/b/mesh.ply --no-align");
  if (!args.parse(argc, argv)) return 0;
  const std::optional<Alignment> alignment = alignmentFor(args);
  SurfaceEvalOptions o;
  o.cap_m = args.getDouble("cap");
  const int samples = args.getInt("samples");
  if (samples < 0) throw Error("--samples must be 0 or more");
  o.reference_samples = static_cast<size_t>(samples);
  const auto start = std::chrono::steady_clock::now();
  Mesh mesh = readPly(args.get("MESH"));
  const Mesh ref = readPly(args.get("REF"));
  if (alignment) {
    const Eigen::Isometry3f a =
        evaluateTrajectory(readTumTrajectory(alignment->gt), readTumTrajectory(alignment->est)).alignment.cast<float>();
    for (auto& v : mesh.vertices) v = a * v;
    if (!args.flagSet("json")) std::cout << "MESH moved into REF's world: " << alignment->est << " aligned to " << alignment->gt << "\n";
  }
  const SurfaceErrors e = evaluateSurface(mesh, ref, o);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (args.flagSet("json")) {
    JsonObject j;
    j.set("corr_m", e.corr_m)
        .set("compl_m", e.compl_m)
        .set("corr_median_m", e.corr_median_m)
        .set("compl_median_m", e.compl_median_m)
        .set("corr_within_1cm", e.corr_within_1cm)
        .set("corr_within_2cm", e.corr_within_2cm)
        .set("compl_within_1cm", e.compl_within_1cm)
        .set("compl_within_2cm", e.compl_within_2cm)
        .set("cap_m", e.cap_m)
        .set("mesh_vertices", e.mesh_vertices)
        .set("reference_samples", e.reference_samples)
        .set("seconds", seconds);
    std::cout << j.str() << "\n";
    return 0;
  }
  std::cout << "distances capped at " << e.cap_m << " m; " << e.mesh_vertices << " mesh vertices, " << e.reference_samples
            << " reference samples, " << fmt(seconds, "%.2f") << " s\n"
            << "CORR   mean " << fmt(e.corr_m) << " m  median " << fmt(e.corr_median_m) << " m  within 1 cm "
            << fmt(100 * e.corr_within_1cm, "%.1f") << " %  within 2 cm " << fmt(100 * e.corr_within_2cm, "%.1f") << " %\n"
            << "COMPL  mean " << fmt(e.compl_m) << " m  median " << fmt(e.compl_median_m) << " m  within 1 cm "
            << fmt(100 * e.compl_within_1cm, "%.1f") << " %  within 2 cm " << fmt(100 * e.compl_within_2cm, "%.1f") << " %\n"
            << keyValueLine({{"corr_m", e.corr_m}, {"compl_m", e.compl_m}}) << "\n";
  return 0;
}

}  // namespace

int evalCommand(int argc, char** argv) {
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") {
    std::cout << kUsage;
    return argc < 2 ? 2 : 0;
  }
  const std::string what = argv[1];
  if (what == "traj") return trajMain(argc - 1, argv + 1);
  if (what == "surface") return surfaceMain(argc - 1, argv + 1);
  throw Error("unknown evaluation '" + what + "'; choose traj or surface (rekon eval --help)");
}

}  // namespace rekon::eval
