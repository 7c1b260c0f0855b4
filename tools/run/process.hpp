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
  // Starts the process again after it ended, with `extra_args` after the
  // original ones (replacing those of an earlier restart); its log is appended to.
  void restart(const std::vector<std::string>& extra_args);
  int restarts() const { return restarts_; }
  // Resident set size in MiB from /proc, or nullopt when not running.
  std::optional<double> rssMb() const;
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
  std::vector<std::string> args_, extra_args_;
  std::string log_path_;
  int restarts_ = 0;
  pid_t pid_ = -1;
  std::optional<int> status_;
};

// "exited with status 1", "was killed by signal 9 (Killed)": how a child ended,
// from poll()'s status.
std::string describeExit(int status);

// Folder of the running executable (where the service binaries are built).
std::string executableDir();

}  // namespace rekon
