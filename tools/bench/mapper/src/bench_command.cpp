#include "rekon/mapper_bench/bench_command.hpp"

#include <iostream>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/longrun/longrun.hpp"

namespace rekon::mapper_bench {

int benchCommand(int argc, char** argv) {
  const std::string usage =
      "usage: rekon bench keyframes --dataset DIR --out DIR [...]      (paper Figure 5)\n"
      "       rekon bench reintegration --dataset DIR --out DIR [...]  (paper Figure 7)\n"
      "       rekon bench peers --dataset DIR [--frames N] [--out DIR]  (TSDF integration against OpenCV and Open3D)\n"
      "       rekon bench scaling --out DIR [--laps 3] [...]           (integration time as the map grows)\n"
      "       rekon bench longrun --out DIR [--minutes M] [--dataset DIR] (a long scan through the services, per minute)\n"
      "       rekon bench SUBCOMMAND --help for the options\n";
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") {
    std::cout << usage;
    return 0;
  }
  const std::string what = argv[1];
  std::string program = std::string(argv[0]) + " " + what;
  argv[1] = program.data();  // the subcommand sees "rekon bench NAME" as its program
  if (what == "keyframes") return benchKeyframesCommand(argc - 1, argv + 1);
  if (what == "reintegration") return benchReintegrationCommand(argc - 1, argv + 1);
  if (what == "peers") return benchPeersCommand(argc - 1, argv + 1);
  if (what == "scaling") return benchScalingCommand(argc - 1, argv + 1);
  if (what == "longrun") return longrun::benchLongrunCommand(argc - 1, argv + 1);
  throw Error("rekon bench: unknown subcommand '" + what + "'; use keyframes, reintegration, peers, scaling or longrun");
}

}  // namespace rekon::mapper_bench
