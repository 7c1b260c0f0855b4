#include "realsense_probe.hpp"

#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <sstream>

#include "process.hpp"

namespace rekon {
namespace {

struct Output {
  int status = -1;  // the exit code; -1 when it could not run or was killed
  std::vector<std::string> lines;  // stdout and stderr together
};

// Runs build/bin/rekon-realsense ARGS (no shell: a path may hold anything).
Output runRealSense(const std::vector<std::string>& args) {
  const std::string binary = executableDir() + "/rekon-realsense";
  Output out;
  if (!std::filesystem::exists(binary)) {
    out.lines.push_back("rekon-realsense is not part of this build (" + binary + "); build it: cmake --build build");
    return out;
  }
  std::vector<char*> argv{const_cast<char*>(binary.c_str())};
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  int fds[2];
  if (::pipe(fds) != 0) return out;
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::dup2(fds[1], STDOUT_FILENO);
    ::dup2(fds[1], STDERR_FILENO);
    ::close(fds[0]);
    ::close(fds[1]);
    ::execv(binary.c_str(), argv.data());
    ::_exit(127);
  }
  ::close(fds[1]);
  std::string text;
  char buf[4096];
  for (ssize_t n; (n = ::read(fds[0], buf, sizeof buf)) > 0;) text.append(buf, static_cast<size_t>(n));
  ::close(fds[0]);
  int status = 0;
  if (pid > 0 && ::waitpid(pid, &status, 0) == pid && WIFEXITED(status)) out.status = WEXITSTATUS(status);
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);)
    if (!line.empty()) out.lines.push_back(line);
  return out;
}

// rekon-realsense's last line without its "rekon-realsense: error: ".
std::string errorLine(const Output& out) {
  if (out.lines.empty()) return "rekon-realsense could not be run (exit " + std::to_string(out.status) + ")";
  std::string line = out.lines.back();
  const std::string prefix = "rekon-realsense: error: ";
  if (line.rfind(prefix, 0) == 0) line = line.substr(prefix.size());
  return line;
}

}  // namespace

RealSenseListing listRealSenseCameras() {
  const Output out = runRealSense({"--list"});
  RealSenseListing listing;
  if (out.status != 0) {
    listing.error = errorLine(out);
    return listing;
  }
  for (const auto& line : out.lines)
    if (line.rfind("realsense:", 0) == 0) listing.cameras.push_back(line);
  return listing;
}

std::string whyRealSenseCannotOpen(const std::vector<std::string>& args) {
  std::vector<std::string> all{"--check"};
  all.insert(all.end(), args.begin(), args.end());
  const Output out = runRealSense(all);
  return out.status == 0 ? "" : errorLine(out);
}

}  // namespace rekon
