#pragma once
// The table of `rekon` subcommands.
#include <vector>

namespace rekon {

struct Command {
  const char* name;
  const char* summary;
  int (*main)(int argc, char** argv);  // argv[0] is "rekon NAME"
};

const std::vector<Command>& commands();

}  // namespace rekon
