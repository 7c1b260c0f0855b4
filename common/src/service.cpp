#include "rekon/common/service.hpp"

#include <signal.h>
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <thread>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/common/memory.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/service_stats_t.hpp"
#include "rekon_msgs/shutdown_t.hpp"

namespace rekon {
namespace {

std::atomic<bool> g_signal_stop{false};
void onSignal(int) { g_signal_stop.store(true); }

int64_t nowMicros() {
  return std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::system_clock::now().time_since_epoch()).count();
}

}  // namespace

std::string hostName() {
  char buf[256] = {0};
  gethostname(buf, sizeof(buf) - 1);
  return buf;
}

rekon_msgs::done_t doneMessage(const std::string& service, int64_t last_frame_id) {
  rekon_msgs::done_t done{};
  done.service = service;
  done.pid = getpid();
  done.last_frame_id = last_frame_id;
  return done;
}

double peakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;
}

double currentRssMb() {
  std::ifstream statm("/proc/self/statm");
  long long pages_total = 0, pages_resident = 0;
  if (!(statm >> pages_total >> pages_resident)) return 0.0;
  return static_cast<double>(pages_resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) / 1048576.0;
}

struct ServiceContext::Threads {
  std::atomic<bool> stop_requested{false};
  std::atomic<bool> threads_stop{false};
  std::atomic<bool> exited_sent{false};
  std::mutex state_mutex;
  std::condition_variable state_changed;  // wakes the heartbeat thread: a new state goes out at once
  std::string state = "starting";
  std::thread bus_thread, heartbeat_thread;
  std::mutex live_mutex;
  std::map<std::string, double> live;  // setLive's numbers
  bool live_changed = false;
};

namespace {

// A service's stats as one STATS message.
rekon_msgs::service_stats_t statsMessage(const std::string& service, const JsonObject& json) {
  rekon_msgs::service_stats_t m{};
  m.service = service;
  m.utime = nowMicros();
  m.json = json.str(0);
  return m;
}

}  // namespace

ServiceContext::ServiceContext(std::string name, Config config, std::string out_dir, const ArgParser& args)
    : name_(std::move(name)), config_(std::move(config)), out_dir_(std::move(out_dir)), args_(args),
      bus_(makeBus(BusOptions::fromConfig(config_))), lifecycle_(LifecycleTimes::fromConfig(config_)),
      threads_(std::make_unique<Threads>()) {
  bus_->subscribe<rekon_msgs::shutdown_t>(channel::kShutdown, [this](const rekon_msgs::shutdown_t& m) {
    spdlog::info("shutdown requested ({})", m.reason);
    requestStop();
  });
}

ServiceContext::~ServiceContext() { stopThreads(); }

bool ServiceContext::stopRequested() const { return threads_->stop_requested.load() || g_signal_stop.load(); }
void ServiceContext::requestStop() { threads_->stop_requested.store(true); }

void ServiceContext::setState(const std::string& state) {
  {
    std::lock_guard<std::mutex> lock(threads_->state_mutex);
    // "exited" is an instance's last word (stopThreads): runInContext's
    // "finished" after a body that stopped its threads itself once went out
    // after it, and its peers then waited for its silence instead.
    if (threads_->state == state || threads_->exited_sent.load()) return;
    threads_->state = state;
  }
  // On the bus before anything the caller publishes next: a restarted mapper
  // says "running" before its resume point, so the tracker knows the new
  // instance before the frames the player sends it again (the heartbeat
  // thread, woken below, was once later than those under load: the tracker
  // took them for a repeat to the old instance and did not answer them).
  try {
    bus_->publish(channel::kHeartbeat, heartbeat());
  } catch (const std::exception& e) {
    spdlog::warn("heartbeat for state {} not published: {}", state, e.what());
  }
  threads_->state_changed.notify_all();
}

void ServiceContext::setLive(const std::string& key, double value) {
  std::lock_guard<std::mutex> lock(threads_->live_mutex);
  double& v = threads_->live[key];
  threads_->live_changed |= v != value;
  v = value;
}

void ServiceContext::publishLive() {
  JsonObject json;
  {
    std::lock_guard<std::mutex> lock(threads_->live_mutex);
    if (!threads_->live_changed) return;
    threads_->live_changed = false;
    for (const auto& [key, value] : threads_->live) json.set(key, value);
  }
  bus_->publish(channel::kStats, statsMessage(name_, json));
}

void ServiceContext::start() {
  threads_->bus_thread = std::thread([this] {
    try {
      bus_->spin(threads_->threads_stop);
    } catch (...) {  // a handler's exception of any type: one line, and the service stops cleanly
      spdlog::error("{}", currentExceptionLine());
      requestStop();
    }
  });
  threads_->heartbeat_thread = std::thread([this] {
    try {
      heartbeatLoop();
    } catch (...) {  // peers will see this instance fall silent; the service stops with its outputs
      spdlog::error("heartbeat thread: {}", currentExceptionLine());
      requestStop();
    }
  });
}

rekon_msgs::heartbeat_t ServiceContext::heartbeat() const {
  static const std::string host = hostName();
  rekon_msgs::heartbeat_t hb{};
  hb.service = name_;
  hb.pid = getpid();
  hb.host = host;
  hb.utime = nowMicros();
  hb.last_frame_id = last_frame_.load();
  std::lock_guard<std::mutex> lock(threads_->state_mutex);
  hb.state = threads_->state;
  return hb;
}

void ServiceContext::heartbeatLoop() {
  const auto interval = std::chrono::duration_cast<std::chrono::milliseconds>(
      std::chrono::duration<double>(lifecycle_.heartbeat_s));
  auto last_live = std::chrono::steady_clock::now();
  while (!threads_->threads_stop.load()) {
    if (std::chrono::steady_clock::now() - last_live >= std::chrono::seconds(1)) {
      last_live = std::chrono::steady_clock::now();
      publishLive();
    }
    const rekon_msgs::heartbeat_t hb = heartbeat();
    bus_->publish(channel::kHeartbeat, hb);
    // Every heartbeat_s, and at once when the state changes (a player waiting
    // for its consumers starts as soon as they are running).
    std::unique_lock<std::mutex> lock(threads_->state_mutex);
    threads_->state_changed.wait_for(lock, interval,
                                     [&] { return threads_->threads_stop.load() || threads_->state != hb.state; });
  }
}

void ServiceContext::stopThreads() {
  {
    std::lock_guard<std::mutex> lock(threads_->state_mutex);  // so that the heartbeat thread cannot miss it
    threads_->threads_stop.store(true);
  }
  threads_->state_changed.notify_all();
  if (threads_->bus_thread.joinable()) threads_->bus_thread.join();
  if (threads_->heartbeat_thread.joinable()) threads_->heartbeat_thread.join();
  // Said once: this instance handles no message any more. Watchers count a
  // done instance as finished only after this (or its silence), so that one
  // killed after its done_t is waited for until its restart is done.
  if (threads_->exited_sent.exchange(true)) return;
  {
    std::lock_guard<std::mutex> lock(threads_->state_mutex);
    threads_->state = "exited";
  }
  try {
    bus_->publish(channel::kHeartbeat, heartbeat());
  } catch (...) {
    spdlog::warn("the exit heartbeat was not published: {}", currentExceptionLine());
  }
}

void ServiceContext::writeStats() {
  stats_.set("peak_rss_mb", peakRssMb());
  if (bus_->malformedCount() > 0) stats_.set("malformed_messages", static_cast<long long>(bus_->malformedCount()));
  if (bus_->droppedCount() > 0) stats_.set("dropped_messages", static_cast<long long>(bus_->droppedCount()));
  try {
    bus_->publish(channel::kStats, statsMessage(name_, stats_));
  } catch (const std::exception& e) {  // the file below matters more than the watchers
    spdlog::warn("stats not published on the bus: {}", e.what());
  }
  if (out_dir_.empty() || !stats_file_) return;
  stats_.save((std::filesystem::path(out_dir_) / (name_ + "_stats.json")).string());
}

LifecycleTimes LifecycleTimes::fromConfig(const Config& config) {
  const double load = config.getDouble("lifecycle.load_factor");
  if (!(load >= 1.0)) throw Error("lifecycle.load_factor must be 1 or more (it only ever lengthens the timeouts)");
  auto seconds = [&](const std::string& key) {
    const double s = config.getDouble("lifecycle." + key);
    if (!(s > 0.0)) throw Error("lifecycle." + key + " must be a positive number of seconds");
    return s * load;
  };
  LifecycleTimes t;
  t.heartbeat_s = config.getDouble("lifecycle.heartbeat_s");  // the pace, not a wait: not scaled
  if (!(t.heartbeat_s > 0.0)) throw Error("lifecycle.heartbeat_s must be a positive number of seconds");
  t.silence_s = seconds("silence_s");
  t.silence_gaps = config.getDouble("lifecycle.silence_gaps");
  if (!(t.silence_gaps >= 2.0)) throw Error("lifecycle.silence_gaps must be 2 or more");
  t.peer_seen_s = seconds("peer_seen_s");
  t.replay_answer_s = seconds("replay_answer_s");
  if (t.silence_s < 4 * t.heartbeat_s) throw Error("lifecycle.silence_s must be at least 4 heartbeats (lifecycle.heartbeat_s)");
  return t;
}

PeerWatch::PeerWatch(Bus& bus, LifecycleTimes times) : times_(times) {
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat,
                                         [this](const rekon_msgs::heartbeat_t& hb) { onHeartbeat(hb); });
  bus.subscribe<rekon_msgs::done_t>(channel::kDone, [this](const rekon_msgs::done_t& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    Peer& p = peers_[m.service];
    if (current(p, m.service, m.pid)) p.done = true;
  });
}

Incarnations::Seen Incarnations::note(const std::string& service, int pid) {
  auto [it, first] = current_.try_emplace(service, pid);
  if (first || it->second == pid) return first ? Seen::kNew : Seen::kCurrent;
  std::set<int>& superseded = superseded_[service];
  if (superseded.count(pid) > 0) return Seen::kSuperseded;
  superseded.insert(it->second);
  it->second = pid;
  return Seen::kNew;
}

bool PeerWatch::current(Peer& p, const std::string& service, int pid) {
  switch (incarnations_.note(service, pid)) {
    case Incarnations::Seen::kSuperseded:
      return false;  // a late message of an instance that was replaced
    case Incarnations::Seen::kNew: {
      const int instances = p.instances;
      p = Peer{};
      p.pid = pid;
      p.instances = instances;
      return true;
    }
    case Incarnations::Seen::kCurrent:
      break;
  }
  return true;
}

void PeerWatch::onHeartbeat(const rekon_msgs::heartbeat_t& hb) {
  std::vector<std::function<void(const std::string&, int)>> call;
  int instance = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Peer& p = peers_[hb.service];
    if (!current(p, hb.service, hb.pid)) return;
    const auto now = Clock::now();
    if (p.last_heartbeat != Clock::time_point{}) p.longest_gap = std::max(p.longest_gap, now - p.last_heartbeat);
    p.last_heartbeat = now;
    p.host = hb.host;
    p.state = hb.state;
    p.exited = hb.state == "exited";
    // "starting" has not subscribed yet: current and alive, but not an instance to serve yet.
    if (hb.state != "starting" && !p.served) {
      p.served = true;
      instance = ++p.instances;
      if (instance > 1) call = callbacks_;
    }
  }
  for (const auto& f : call) f(hb.service, instance);
}

void PeerWatch::onNewInstance(std::function<void(const std::string&, int)> f) {
  std::lock_guard<std::mutex> lock(mutex_);
  callbacks_.push_back(std::move(f));
}

std::optional<PeerWatch::Peer> PeerWatch::peer(const std::string& service) const {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = peers_.find(service);
  // A done_t alone (its heartbeat not seen yet) makes an entry but no peer.
  if (it == peers_.end() || it->second.last_heartbeat == Clock::time_point{}) return std::nullopt;
  return it->second;
}

bool PeerWatch::silent(const Peer& p) const {
  const auto base = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(times_.silence_s));
  const auto gaps = std::chrono::duration_cast<Clock::duration>(p.longest_gap * times_.silence_gaps);
  return p.last_heartbeat != Clock::time_point{} && Clock::now() - p.last_heartbeat > std::max(base, gaps);
}

bool PeerWatch::alive(const std::string& service) const {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = peers_.find(service);
  return it != peers_.end() && it->second.last_heartbeat != Clock::time_point{} && !silent(it->second);
}

bool PeerWatch::gone(const std::string& service) const {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = peers_.find(service);
  return it != peers_.end() && silent(it->second);
}

bool PeerWatch::done(const std::string& service) const {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = peers_.find(service);
  return it != peers_.end() && it->second.done;
}

bool PeerWatch::finishedLocked(const std::string& name) const {
  auto it = peers_.find(name);
  if (it == peers_.end()) return true;  // not part of this run
  const Peer& p = it->second;
  if (p.last_heartbeat == Clock::time_point{}) return p.done;  // a stand-in without heartbeats
  return (p.done && p.exited) || silent(p);
}

bool PeerWatch::finished(const std::vector<std::string>& names) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::all_of(names.begin(), names.end(), [&](const std::string& n) { return finishedLocked(n); });
}

int runInContext(ServiceContext& ctx, const std::function<void(ServiceContext&)>& body) {
  try {
    ctx.start();
    body(ctx);
    ctx.setState("finished");
    ctx.stopThreads();
    ctx.writeStats();
    return 0;
  } catch (...) {
    spdlog::error("{}", currentExceptionLine());
    ctx.stopThreads();
    try {
      ctx.writeStats();  // whatever was measured before the error is kept
    } catch (...) {
      spdlog::error("{}", currentExceptionLine());
    }
    return 1;
  }
}

int runService(int argc, char** argv, const std::string& name, const std::string& summary,
               const std::function<void(ArgParser&)>& add_options, const std::function<void(ServiceContext&)>& body) {
  // Started as a `rekon` subcommand (rekon listen, rekon view), its usage says that command.
  const bool subcommand = argc > 0 && std::string(argv[0]).rfind("rekon ", 0) == 0;
  ArgParser args(subcommand ? std::string(argv[0]) : "rekon-" + name, summary);
  args.option("config", "YAML config laid over config/default.yaml")
      .repeated("set", "override one config key, e.g. --set log.level=debug")
      .option("out", "folder for this service's outputs and stats (created if missing)");
  if (add_options) add_options(args);
  std::unique_ptr<ServiceContext> ctx;
  try {
    if (!args.parse(argc, argv)) return 0;
    Config config = Config::load(args.get("config"), args.all("set"));
    setupLogging(name, config.getString("log.level"));
    const std::string out = args.get("out");
    if (!out.empty()) createOutputFolder(out);
    keepFreedMemory();
    signal(SIGINT, onSignal);
    signal(SIGTERM, onSignal);
    signal(SIGPIPE, SIG_IGN);
    ctx = std::make_unique<ServiceContext>(name, std::move(config), out, args);
  } catch (...) {  // before the service runs: nothing measured yet
    const std::string line = currentExceptionLine();
    if (spdlog::default_logger()) spdlog::error("{}", line);
    else std::cerr << "rekon-" << name << ": error: " << line << "\n";
    return 1;
  }
  return runInContext(*ctx, body);
}

}  // namespace rekon
