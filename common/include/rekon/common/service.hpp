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
#include <set>
#include <string>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/json.hpp"

namespace rekon_msgs {
class done_t;
class heartbeat_t;
}

namespace rekon {

// How long services wait for each other (config lifecycle.*, one place):
// every time scaled by lifecycle.load_factor.
struct LifecycleTimes {
  double heartbeat_s = 0.5;
  double silence_s = 5.0;    // a peer silent this long has exited for good...
  double silence_gaps = 6;   // ...and at least this many times its longest heartbeat gap
  double peer_seen_s = 1.5;
  double replay_answer_s = 2.0;
  static LifecycleTimes fromConfig(const Config& config);
};

class ServiceContext {
 public:
  ServiceContext(std::string name, Config config, std::string out_dir, const ArgParser& args);
  ~ServiceContext();

  const std::string& name() const { return name_; }
  const Config& config() const { return config_; }
  const std::string& outDir() const { return out_dir_; }  // "" when not given
  const ArgParser& args() const { return args_; }
  Bus& bus() { return *bus_; }
  const LifecycleTimes& lifecycle() const { return lifecycle_; }

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
  // This instance's stats go on the bus only: <name>_stats.json stays the
  // earlier instance's, which did the work (a restart that finds it done).
  void keepEarlierStatsFile() { stats_file_ = false; }

  // Starts the bus thread (handlers run there) and the heartbeat thread.
  void start();
  void stopThreads();

 private:
  struct Threads;
  void publishLive();  // the heartbeat thread, once a second
  void heartbeatLoop();
  rekon_msgs::heartbeat_t heartbeat() const;  // this instance's, now
  std::string name_;
  Config config_;
  std::string out_dir_;
  const ArgParser& args_;
  std::unique_ptr<Bus> bus_;
  LifecycleTimes lifecycle_;
  std::atomic<int64_t> last_frame_{-1};
  std::unique_ptr<Threads> threads_;
  JsonObject stats_;
  bool stats_file_ = true;
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

// Which process instance (pid) of each service is the current one: the first
// message of a pid not seen before makes it current, and the instance it
// replaced is superseded for good (a late message of a killed instance must
// not bring it back). Not thread-safe: its owner locks.
class Incarnations {
 public:
  enum class Seen { kCurrent, kNew, kSuperseded };
  Seen note(const std::string& service, int pid);
  // The current pid of `service`, 0 before its first message.
  int current(const std::string& service) const {
    auto it = current_.find(service);
    return it == current_.end() ? 0 : it->second;
  }

 private:
  std::map<std::string, int> current_;
  std::map<std::string, std::set<int>> superseded_;
};

// What a service knows of its peers from their heartbeats and done_t
// messages, keyed on the instance (the sender's pid). The first message of a
// pid not seen before, whatever its state, makes it the current instance: the
// one before is superseded, and nothing it sends later counts (a done_t of a
// killed instance never finishes its successor). A current instance seen
// past "starting" is announced to onNewInstance (after the first) on the bus
// thread. docs/faults.md has the contract as a table.
class PeerWatch {
 public:
  using Clock = std::chrono::steady_clock;
  struct Peer {
    int pid = 0;             // the current instance
    int instances = 0;       // distinct pids seen past "starting"
    bool done = false;       // done_t from the current instance
    bool exited = false;     // the current instance said it handles nothing more (heartbeat "exited")
    bool served = false;     // the current instance was seen past "starting"
    std::string host, state;
    Clock::time_point last_heartbeat{};
    Clock::duration longest_gap{};  // between two heartbeats of the current instance
  };
  explicit PeerWatch(Bus& bus, LifecycleTimes times = {});
  // `f(service, instance)` for every instance after a service's first.
  void onNewInstance(std::function<void(const std::string& service, int instance)> f);
  // A service whose heartbeat has been seen; nullopt before its first one.
  std::optional<Peer> peer(const std::string& service) const;
  // Heartbeats seen, and not silent (see silent()).
  bool alive(const std::string& service) const;
  // Heartbeats were seen and have stopped for the watch's silence: gone for good.
  bool gone(const std::string& service) const;
  // done_t from the current instance of `service` (a stand-in that sends
  // done_t without heartbeats, like rekon-replay, counts too).
  bool done(const std::string& service) const;
  // True when every service in `names` is finished: never seen at all (not
  // part of this run), done and exited (or done with no heartbeat ever), or
  // gone. A done instance that was killed before it exited is not finished
  // until its restart is done too, or until it stays silent: services linger
  // until their downstream services are finished, so that a restarted one
  // still gets what it needs from them.
  bool finished(const std::vector<std::string>& names) const;

 private:
  void onHeartbeat(const rekon_msgs::heartbeat_t& hb);
  // Under the lock: `pid` is a message of `service`'s; false when it comes
  // from a superseded instance. A new pid becomes the current instance.
  bool current(Peer& p, const std::string& service, int pid);
  Incarnations incarnations_;
  // Heartbeats seen, none for silence_s and silence_gaps x the longest gap.
  bool silent(const Peer& p) const;
  bool finishedLocked(const std::string& name) const;

  const LifecycleTimes times_;
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

// done_t of this process (its pid) for `service`: the services and stand-ins
// that finish in its name.
rekon_msgs::done_t doneMessage(const std::string& service, int64_t last_frame_id);

// This machine's host name (as heartbeats carry it).
std::string hostName();

// Peak resident set size of this process in MiB.
double peakRssMb();
// Resident set size of this process now, in MiB (/proc/self/statm; 0 where unreadable).
double currentRssMb();

}  // namespace rekon
