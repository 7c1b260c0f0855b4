// `rekon view`: rekon-viewer in the foreground (the same process, by exec), so
// that it watches whatever runs on the bus: a rekon run, a live camera
// session, or lcm-logplayer replaying a recorded log.
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "commands.hpp"
#include "rekon/common/error.hpp"

namespace rekon {

int viewCommand(int argc, char** argv) {
  // Beside this binary, as every service is (build/bin).
  const std::string viewer = (std::filesystem::read_symlink("/proc/self/exe").parent_path() / "rekon-viewer").string();
  std::vector<std::string> args = {"rekon view"};  // its usage and errors name the command the user typed
  for (int i = 1; i < argc; ++i) args.emplace_back(argv[i]);  // rekon-viewer parses and documents them (--help)
  std::vector<char*> exec_args;
  for (auto& a : args) exec_args.push_back(a.data());
  exec_args.push_back(nullptr);
  execv(viewer.c_str(), exec_args.data());
  throw Error(viewer + ": cannot start (" + std::strerror(errno) + "); build it (tools/rekon setup)");
}

}  // namespace rekon
