// `rekon SUBCOMMAND ...`: dispatches to the subcommands in commands.cpp.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstring>
#include <iostream>
#include <string>
#include <vector>

#include "commands.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/memory.hpp"
#include "version_info.hpp"

int main(int argc, char** argv) {
  rekon::keepFreedMemory();  // the benchmarks run the services' code: the same allocator settings
  const auto& table = rekon::commands();
  if (argc < 2 || std::strcmp(argv[1], "--help") == 0 || std::strcmp(argv[1], "-h") == 0) {
    std::cout << "usage: rekon COMMAND [options]   (rekon COMMAND --help for its options and examples)\n"
                 "       rekon --version\n\ncommands:\n";
    size_t width = 0;
    for (const auto& c : table) width = std::max(width, std::strlen(c.name) + 2);
    for (const auto& c : table) std::cout << "  " << c.name << std::string(width - std::strlen(c.name), ' ') << c.summary << "\n";
    std::cout << "\nexamples:\n  rekon demo\n  rekon run --dataset ../shared/data/7scenes_loop_1000 --out out/7scenes --view\n"
                 "  rekon eval traj out/demo/room_0_data/groundtruth.txt out/demo/trajectory.txt\n";
    return argc < 2 ? 2 : 0;
  }
  if (std::strcmp(argv[1], "--version") == 0) {
    std::cout << "rekon, git revision " << rekon::gitRevision() << ", " << rekon::buildType() << " build\n";
    return 0;
  }
  for (const auto& c : table) {
    if (argv[1] != std::string(c.name)) continue;
    std::string program = std::string("rekon ") + c.name;
    argv[1] = program.data();
    try {
      return c.main(argc - 1, argv + 1);
    } catch (...) {  // any exception: one line and a non-zero exit, never std::terminate
      std::string line = rekon::currentExceptionLine();
      if (line.rfind(program + ": ", 0) == 0) line.erase(0, program.size() + 2);  // the parser's errors name it already
      std::cerr << program << ": error: " << line << "\n";
      return 1;
    }
  }
  std::vector<std::string> names;
  for (const auto& c : table) names.emplace_back(c.name);
  std::cerr << "rekon: unknown command '" << argv[1] << "'" << rekon::didYouMean(argv[1], names)
            << "; run rekon --help for the list\n";
  return 2;
}
