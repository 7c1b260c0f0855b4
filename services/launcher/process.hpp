#pragma once
// Child processes of the launcher: started with their output in a log file,
// polled without blocking, stopped with SIGTERM and, after a grace period, SIGKILL.
#include <sys/types.h>

#include <optional>
#include <string>
#include <vector>

namespace rekon {

class ChildProcess {
 public:
  ChildProcess(std::string name, std::string binary, std::vector<std::string> args, std::string log_path);
  void start();  // throws rekon::Error when the binary cannot be started
  // Exit status once the process has ended (128 + signal for a signal), else nullopt.
  std::optional<int> poll();
  void terminate();  // SIGTERM
  void kill();       // SIGKILL
  bool running() const { return pid_ > 0 && !status_; }
  const std::string& name() const { return name_; }
  const std::string& logPath() const { return log_path_; }
  pid_t pid() const { return pid_; }

 private:
  std::string name_, binary_;
  std::vector<std::string> args_;
  std::string log_path_;
  pid_t pid_ = -1;
  std::optional<int> status_;
};

// Folder of the running executable (where the service binaries are built).
std::string executableDir();

}  // namespace rekon
