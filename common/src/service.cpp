#include "rekon/common/service.hpp"

#include <signal.h>
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <filesystem>
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

double peakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;
}

struct ServiceContext::Threads {
  std::atomic<bool> stop_requested{false};
  std::atomic<bool> threads_stop{false};
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
      bus_(makeBus(BusOptions::fromConfig(config_))), threads_(std::make_unique<Threads>()) {
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
    if (threads_->state == state) return;
    threads_->state = state;
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
    const std::string host = hostName();
    auto last_live = std::chrono::steady_clock::now();
    while (!threads_->threads_stop.load()) {
      if (std::chrono::steady_clock::now() - last_live >= std::chrono::seconds(1)) {
        last_live = std::chrono::steady_clock::now();
        publishLive();
      }
      rekon_msgs::heartbeat_t hb{};
      hb.service = name_;
      hb.pid = getpid();
      hb.host = host;
      hb.utime = nowMicros();
      hb.last_frame_id = last_frame_.load();
      {
        std::lock_guard<std::mutex> lock(threads_->state_mutex);
        hb.state = threads_->state;
      }
      bus_->publish(channel::kHeartbeat, hb);
      // Every 0.5 s, and at once when the state changes (a player waiting
      // for its consumers starts as soon as they are running).
      std::unique_lock<std::mutex> lock(threads_->state_mutex);
      threads_->state_changed.wait_for(lock, std::chrono::milliseconds(500),
                                       [&] { return threads_->threads_stop.load() || threads_->state != hb.state; });
    }
  });
}

void ServiceContext::stopThreads() {
  {
    std::lock_guard<std::mutex> lock(threads_->state_mutex);  // so that the heartbeat thread cannot miss it
    threads_->threads_stop.store(true);
  }
  threads_->state_changed.notify_all();
  if (threads_->bus_thread.joinable()) threads_->bus_thread.join();
  if (threads_->heartbeat_thread.joinable()) threads_->heartbeat_thread.join();
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
  if (out_dir_.empty()) return;
  stats_.save((std::filesystem::path(out_dir_) / (name_ + "_stats.json")).string());
}

PeerWatch::PeerWatch(Bus& bus) {
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [this](const rekon_msgs::heartbeat_t& hb) {
    std::vector<std::function<void(const std::string&, int)>> call;
    int instance = 0;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      Peer& p = peers_[hb.service];
      p.last_heartbeat = Clock::now();
      p.host = hb.host;
      p.state = hb.state;
      // "starting" has not subscribed yet: it counts as alive, not as an instance to serve.
      if (hb.state != "starting" && hb.pid != p.pid) {
        p.pid = hb.pid;
        p.done = false;
        instance = ++p.instances;
        if (instance > 1) call = callbacks_;
      }
    }
    for (const auto& f : call) f(hb.service, instance);
  });
  bus.subscribe<rekon_msgs::done_t>(channel::kDone, [this](const rekon_msgs::done_t& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    peers_[m.service].done = true;
  });
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

bool PeerWatch::alive(const std::string& service, double silence_s) const {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = peers_.find(service);
  return it != peers_.end() && it->second.last_heartbeat != Clock::time_point{} &&
         Clock::now() - it->second.last_heartbeat < std::chrono::duration<double>(silence_s);
}

bool PeerWatch::finished(const std::vector<std::string>& names, double silence_s) const {
  const auto silence = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(silence_s));
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& n : names) {
    auto it = peers_.find(n);
    if (it == peers_.end() || it->second.done) continue;
    if (it->second.last_heartbeat != Clock::time_point{} && Clock::now() - it->second.last_heartbeat > silence) continue;
    return false;
  }
  return true;
}

void PeerWatch::waitUntilFinished(const std::vector<std::string>& names, double silence_s, const ServiceContext& ctx) const {
  while (!ctx.stopRequested() && !finished(names, silence_s)) std::this_thread::sleep_for(std::chrono::milliseconds(50));
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
  ArgParser args("rekon-" + name, summary);
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
