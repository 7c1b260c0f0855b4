#pragma once
// What every rekon service process shares: its command line (--config, --set,
// --out, --help), logging, the bus with a thread that dispatches messages, a
// heartbeat, live numbers on STATS, stopping on SIGINT/SIGTERM or a shutdown
// message, and writing its statistics (<out>/<name>_stats.json, with
// peak_rss_mb) at exit.
#include <atomic>
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/json.hpp"

namespace rekon {

class ServiceContext {
 public:
  ServiceContext(std::string name, Config config, std::string out_dir, const ArgParser& args);
  ~ServiceContext();

  const std::string& name() const { return name_; }
  const Config& config() const { return config_; }
  const std::string& outDir() const { return out_dir_; }  // "" when not given
  const ArgParser& args() const { return args_; }
  Bus& bus() { return *bus_; }

  // True once SIGINT/SIGTERM or a shutdown message arrived.
  bool stopRequested() const;
  void requestStop();
  // Reported in heartbeats.
  void setState(const std::string& state);
  void setLastFrame(int64_t frame_id) { last_frame_ = frame_id; }

  // Live numbers for whoever watches the bus (the viewer's status panel):
  // any thread may set them, each under the key its final stats use; the
  // heartbeat thread publishes them all on STATS once a second when one changed.
  void setLive(const std::string& key, double value);

  // Filled by the service; written to <out>/<name>_stats.json at exit and
  // published on STATS, so that watchers end with the final numbers.
  JsonObject& stats() { return stats_; }
  void writeStats();

  // Starts the bus thread (handlers run there) and the heartbeat thread.
  void start();
  void stopThreads();

 private:
  struct Threads;
  void publishLive();  // the heartbeat thread, once a second
  std::string name_;
  Config config_;
  std::string out_dir_;
  const ArgParser& args_;
  std::unique_ptr<Bus> bus_;
  std::atomic<int64_t> last_frame_{-1};
  std::unique_ptr<Threads> threads_;
  JsonObject stats_;
};

// Stops the bus and heartbeat threads when it goes out of scope. A service
// body declares one right after the state its bus handlers use, so that no
// handler runs on that state once it is destroyed — on return and on an
// exception alike.
class StopThreadsOnExit {
 public:
  explicit StopThreadsOnExit(ServiceContext& ctx) : ctx_(ctx) {}
  ~StopThreadsOnExit() { ctx_.stopThreads(); }
  StopThreadsOnExit(const StopThreadsOnExit&) = delete;
  StopThreadsOnExit& operator=(const StopThreadsOnExit&) = delete;

 private:
  ServiceContext& ctx_;
};

// What a service knows of its peers from their heartbeats and done_t
// messages: which process instance of each is alive, and which are done. A
// peer seen "running" under a new pid is a restarted instance (the launcher
// restarts crashed services): its done flag is cleared and the callbacks given
// to onNewInstance run on the bus thread.
class PeerWatch {
 public:
  // Heartbeats come every 0.5 s; a peer silent this long has exited (and was
  // not restarted: the launcher restarts within a fraction of a second).
  static constexpr double kSilenceS = 5.0;
  using Clock = std::chrono::steady_clock;
  struct Peer {
    int pid = 0;             // of the newest instance seen running
    int instances = 0;       // distinct pids seen running
    bool done = false;       // done_t from the current instance
    std::string host, state;
    Clock::time_point last_heartbeat{};
  };
  explicit PeerWatch(Bus& bus);
  // `f(service, instance)` for every instance after a service's first.
  void onNewInstance(std::function<void(const std::string& service, int instance)> f);
  // A service whose heartbeat has been seen; nullopt before its first one.
  std::optional<Peer> peer(const std::string& service) const;
  // A heartbeat from `service` within `silence_s`.
  bool alive(const std::string& service, double silence_s) const;
  // True when every service in `names` is finished: never seen at all (not
  // part of this run), done, or silent for `silence_s` (exited for good).
  // Services linger until their downstream services are finished, so that a
  // restarted one still gets what it needs from them.
  bool finished(const std::vector<std::string>& names, double silence_s) const;
  // Waits until finished(names, silence_s) or ctx.stopRequested().
  void waitUntilFinished(const std::vector<std::string>& names, double silence_s, const class ServiceContext& ctx) const;

 private:
  mutable std::mutex mutex_;
  std::map<std::string, Peer> peers_;
  std::vector<std::function<void(const std::string&, int)>> callbacks_;
};

// Runs `body` in `ctx`: starts its threads, then on return marks it
// finished, stops the threads and writes the stats. Returns the exit code: 0,
// or 1 after logging any exception as one line (stats written all the same).
// runService calls it; a test runs a service's logic in-process with it (over
// a memory:// bus).
int runInContext(ServiceContext& ctx, const std::function<void(ServiceContext&)>& body);

// Runs a service: parses the common options plus those `add_options` adds,
// sets everything up, calls `body` (which returns when the service's work is
// done or ctx.stopRequested()), then writes stats. Returns the exit code:
// 0, or 1 after logging any exception as one line.
int runService(int argc, char** argv, const std::string& name, const std::string& summary,
               const std::function<void(ArgParser&)>& add_options, const std::function<void(ServiceContext&)>& body);

// This machine's host name (as heartbeats carry it).
std::string hostName();

// Peak resident set size of this process in MiB.
double peakRssMb();

}  // namespace rekon
