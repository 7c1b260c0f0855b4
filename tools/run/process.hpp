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
  // The exit status (128 + signal for a signal) the first time the process is
  // seen to have ended, so each end is handled once; nullopt while it runs and
  // after its end was reported (a viewer that failed to bind was reported
  // every 50 ms for a whole run).
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
  bool reported_ = false;  // poll returned status_ already
};

// "exited with status 1", "was killed by signal 9 (Killed)": how a child ended,
// from poll()'s status.
std::string describeExit(int status);
// Whether poll()'s status is a death by a signal (kill -9, a crash, the OOM killer).
bool killedBySignal(int status);

// Folder of the running executable (where the service binaries are built).
std::string executableDir();

}  // namespace rekon
