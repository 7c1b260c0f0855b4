// `rekon synth`: writes a synthetic RGB-D sequence with exact ground truth.
#include <iostream>
#include <sstream>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/json.hpp"
#include "rekon/synth/synth.hpp"

namespace rekon::synth {

int synthCommand(int argc, char** argv) {
  ArgParser args(argv[0], "Write a synthetic RGB-D sequence (TUM layout) with exact trajectory and colored mesh_gt.ply.");
  args.option("scene", "room, corridor or tabletop", "room")
      .option("out", "output folder (created)")
      .option("frames", "number of frames (0 = the scene's default for --laps)", "0")
      .option("laps", "corridor: times round the out-and-back path (each lap after the first adds 5484 frames)", "1")
      .option("seed", "seed of trajectory shake and sensor noise", "1")
      .option("noise", "kinect or none", "kinect")
      .option("drift", "T_PER_M,R_DEG_PER_M: also write drifted_trajectory.txt", "")
      .examples("rekon synth --scene room --out out/room\n"
                "rekon synth --scene corridor --laps 2 --out out/corridor2\n"
                "rekon synth --scene room --frames 60 --drift 0.05,3 --out out/drifted   # with drifted_trajectory.txt");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("out")) throw Error("missing --out DIR; see " + std::string(argv[0]) + " --help");
  SequenceOptions o;
  o.scene = args.get("scene");
  o.frames = args.getInt("frames");
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
  if (!args.get("drift").empty()) {
    std::istringstream ss(args.get("drift"));
    char comma = 0;
    if (!(ss >> o.drift_translation_per_m >> comma >> o.drift_rotation_deg_per_m) || comma != ',' || !ss.eof()) {
      throw Error("--drift '" + args.get("drift") + "' must be T_PER_M,R_DEG_PER_M, e.g. 0.01,0.5");
    }
  }
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
