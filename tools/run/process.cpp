#include "process.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "rekon/common/error.hpp"

namespace rekon {

ChildProcess::ChildProcess(std::string name, std::string binary, std::vector<std::string> args, std::string log_path)
    : name_(std::move(name)), binary_(std::move(binary)), args_(std::move(args)), log_path_(std::move(log_path)) {}

void ChildProcess::start() {
  if (access(binary_.c_str(), X_OK) != 0) throw Error(binary_ + ": not found or not executable; build rekon (tools/rekon setup)");
  const int log_fd = open(log_path_.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  if (log_fd < 0) throw Error(log_path_ + ": cannot open log (" + std::strerror(errno) + "); check the --out folder");
  std::vector<char*> argv;
  argv.push_back(binary_.data());
  for (auto& a : args_) argv.push_back(a.data());
  for (auto& a : extra_args_) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = fork();
  if (pid < 0) {
    close(log_fd);
    throw Error("fork failed starting " + name_ + " (" + std::strerror(errno) + ")");
  }
  if (pid == 0) {
    dup2(log_fd, STDOUT_FILENO);
    dup2(log_fd, STDERR_FILENO);
    close(log_fd);
    // Ctrl-C reaches the launcher, which stops its children in order.
    setpgid(0, 0);
    execv(binary_.c_str(), argv.data());
    _exit(127);
  }
  close(log_fd);
  pid_ = pid;
}

void ChildProcess::restart(const std::vector<std::string>& extra_args) {
  extra_args_ = extra_args;
  status_.reset();
  reported_ = false;
  pid_ = -1;
  ++restarts_;
  start();
}

std::optional<double> ChildProcess::rssMb() const {
  if (!running()) return std::nullopt;
  std::ifstream statm("/proc/" + std::to_string(pid_) + "/statm");
  long long size = 0, resident = 0;
  if (!(statm >> size >> resident)) return std::nullopt;
  return static_cast<double>(resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

bool killedBySignal(int status) { return status > 128; }

std::string describeExit(int status) {
  if (killedBySignal(status)) return "was killed by signal " + std::to_string(status - 128) + " (" + strsignal(status - 128) + ")";
  return "exited with status " + std::to_string(status);
}

std::optional<int> ChildProcess::poll() {
  if (pid_ <= 0 || reported_) return std::nullopt;
  if (!status_) {
    int st = 0;
    const pid_t r = waitpid(pid_, &st, WNOHANG);
    if (r != pid_) return std::nullopt;
    status_ = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  }
  reported_ = true;
  return status_;
}

void ChildProcess::terminate() {
  if (running()) ::kill(pid_, SIGTERM);
}

void ChildProcess::kill() {
  if (running()) ::kill(pid_, SIGKILL);
}

std::string executableDir() {
  return std::filesystem::canonical("/proc/self/exe").parent_path().string();
}

}  // namespace rekon
