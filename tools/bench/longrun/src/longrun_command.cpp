// `rekon bench longrun`: starts the tracker, the optimiser and the mapper as
// rekon run does (same binaries, same live settings), then the frame source
// (rekon-synth-source rendering a scene on the fly, or rekon-player on a
// dataset); samples each service's RSS and the mapper's voxel tiers once a
// second; every 10 s and at the end turns the tables in the run folder into
// longrun.csv, the SVG plots and summary.txt, so a stopped run keeps them.
#include <signal.h>
#include <spdlog/spdlog.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <optional>
#include <thread>

#include "process.hpp"
#include "rekon/common/bus.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_ring.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/longrun/longrun.hpp"
#include "rekon/synth/synth.hpp"
#include "rekon/mapper/store/keyframe_store.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/service_stats_t.hpp"

namespace rekon::longrun {
namespace fs = std::filesystem;
namespace {

using Clock = std::chrono::steady_clock;
std::atomic<bool> g_interrupted{false};
void onInterrupt(int) { g_interrupted.store(true); }
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

constexpr double kTableEveryS = 10.0;  // longrun.csv, plots and summary rewritten this often
constexpr int kStopGraceS = 10;        // SIGTERM to SIGKILL

// The seed of the scene's walk and noise: the source renders it, writeSceneTruth scores it.
constexpr int kSceneSeed = 1;

struct Options {
  std::string scene, dataset, out, config_file, pace;
  std::vector<std::string> sets;
  int frames = 0, laps = 1, render_threads = 1;
  double bucket_s = 60;
};

// The mapper's voxel tiers from its live numbers on STATS, once a second into longrun_tiers.csv.
class TierListener {
 public:
  TierListener(const Config& config, const std::string& path, Clock::time_point zero)
      : bus_(makeBus(BusOptions::fromConfig(config))), out_(path), zero_(zero) {
    out_ << "seconds,active_mb,host_mb,on_disk_mb\n";
    bus_->subscribe<rekon_msgs::service_stats_t>(channel::kStats, [this](const rekon_msgs::service_stats_t& m) {
      if (m.service != "mapper") return;
      try {
        const YAML::Node n = YAML::Load(m.json);
        if (!n["voxels_active_mb"]) return;
        std::lock_guard<std::mutex> lock(mutex_);
        out_ << since(zero_) << ',' << n["voxels_active_mb"].as<double>() << ',' << n["voxels_host_mb"].as<double>(0) << ','
             << n["voxels_on_disk_mb"].as<double>(0) << '\n';
        out_.flush();
      } catch (const YAML::Exception&) {
      }
    });
    // The end of the stream: the source lingers (state "lingering") once its last frame went out.
    bus_->subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [this](const rekon_msgs::heartbeat_t& m) {
      if (m.service != "player" || m.state != "lingering") return;
      std::lock_guard<std::mutex> lock(mutex_);
      if (!stream_end_) stream_end_ = Clock::now();
    });
    thread_ = std::thread([this] {
      while (!stop_) bus_->handle(100);
    });
  }
  std::optional<Clock::time_point> streamEnd() {
    std::lock_guard<std::mutex> lock(mutex_);
    return stream_end_;
  }
  ~TierListener() {
    stop_ = true;
    thread_.join();
  }

 private:
  std::unique_ptr<Bus> bus_;
  std::ofstream out_;
  Clock::time_point zero_;
  std::mutex mutex_;
  std::optional<Clock::time_point> stream_end_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

Config planConfig(const Options& o) {
  Config config = Config::load(o.config_file, o.sets);
  config.set("transport.segment", config.getString("transport.segment") + "_longrun_" + std::to_string(getpid()));
  config.set("mapper.store_segment", config.getString("mapper.store_segment") + "_longrun_" + std::to_string(getpid()));
  if (o.pace == "live") {  // as rekon run behind a source that cannot wait (tools/run/launcher.cpp)
    config.set("player.pacing", "live");
    config.set("player.rate", "1");
    config.set("mapper.when_full", "drop");
    config.set("tracker.loop_when_behind", "fewer");
    config.set("mapper.nice", "10");
    config.set("optimiser.nice", "10");
  } else {
    config.set("player.pacing", "wait");
    config.set("player.rate", "\"max\"");
  }
  if (!o.dataset.empty() && o.frames > 0) config.set("player.max_frames", std::to_string(o.frames));
  return config;
}

std::vector<ChildProcess> planChildren(const Options& o, const Config& config, const std::string& config_path) {
  const std::string bin = executableDir();
  std::vector<ChildProcess> children;
  const std::vector<std::string> common = {"--config", config_path, "--out", o.out};
  for (const auto& s : config.getStringList("run.services")) {
    if (s == "player" || s == "viewer") continue;
    children.emplace_back(s, bin + "/rekon-" + s, common, o.out + "/" + s + ".log");
  }
  std::vector<std::string> args = common;
  if (!o.dataset.empty()) {
    args.insert(args.end(), {"--dataset", o.dataset});
    children.emplace_back("player", bin + "/rekon-player", args, o.out + "/player.log");
  } else {
    args.insert(args.end(), {"--scene", o.scene, "--frames", std::to_string(o.frames), "--laps", std::to_string(o.laps),
                             "--seed", std::to_string(kSceneSeed), "--rate", o.pace == "live" ? "1" : "max",
                             "--render-threads", std::to_string(o.render_threads)});
    children.emplace_back("player", bin + "/rekon-synth-source", args, o.out + "/player.log");
  }
  return children;
}

// The walk's exact poses and the scene's mesh (groundtruth.txt, mesh_gt.ply,
// camera.yaml), written once before the source starts, so the run scores
// itself (rekon eval traj OUT/groundtruth.txt OUT/trajectory.txt) and a
// restarted source starts at once (1.6 s for the building's mesh).
void writeSceneTruth(const Options& o) {
  const auto scene = synth::Scene::make(o.scene);
  const int frames = o.frames > 0 ? o.frames : scene->defaultFrames(o.laps);
  synth::writeGroundTruth(*scene, scene->trajectory(frames, kSceneSeed, o.laps), synth::defaultIntrinsics(), o.out);
}

void writeTables(const Options& o, double end_of_run_s, const std::string& header) {
  const auto buckets = readBuckets(o.out, o.bucket_s, 30.0);
  writeBucketsCsv(buckets, o.out + "/longrun.csv");
  writePlots(buckets, o.out);
  writeSummary(judgeGoals(buckets, o.bucket_s, end_of_run_s), header, o.out + "/summary.txt");
}

int run(const Options& o) {
  if (fs::exists(o.out) && !fs::is_empty(o.out)) throw Error("--out " + o.out + " holds files; give a new or empty folder");
  fs::create_directories(o.out);
  setupLogging("longrun", "info");
  if (o.dataset.empty()) writeSceneTruth(o);
  Config config = planConfig(o);
  const std::string config_path = o.out + "/config.yaml";
  config.save(config_path);
  std::vector<ChildProcess> children = planChildren(o, config, config_path);
  signal(SIGINT, onInterrupt);
  signal(SIGTERM, onInterrupt);
  const std::string header = fmt::format("rekon bench longrun: {} {}, {}, buckets of {:.0f} s",
                                         o.dataset.empty() ? "scene" : "dataset", o.dataset.empty() ? o.scene : o.dataset,
                                         o.pace, o.bucket_s);
  std::optional<TierListener> tiers;
  std::ofstream rss(o.out + "/longrun_rss.csv");
  rss << "seconds,service,rss_mb\n";
  Clock::time_point zero = Clock::now();  // the source's start: the tables' time axis
  std::string failure;
  bool stopping = false;
  try {
    for (auto& c : children) {
      if (c.name() == "player") {
        zero = Clock::now();
        tiers.emplace(config, o.out + "/longrun_tiers.csv", zero);
      }
      c.start();
      spdlog::info("started {} (pid {}), log {}", c.name(), c.pid(), c.logPath());
    }
  } catch (const std::exception& e) {
    failure = e.what();
    stopping = true;
  }
  std::optional<Clock::time_point> source_done, all_done;
  std::vector<std::optional<Clock::time_point>> terminated(children.size());
  Clock::time_point next_rss = Clock::now(), next_table = Clock::now() + std::chrono::seconds(static_cast<int>(kTableEveryS));
  while (true) {
    bool any = false;
    for (auto& c : children) {
      if (const auto status = c.poll()) {
        if (c.name() == "player" && *status == 0 && !source_done) {
          source_done = Clock::now();
          spdlog::info("the source has finished; waiting for the services' final steps");
        }
        if (*status != 0 && !stopping) {
          failure = "rekon-" + c.name() + " " + describeExit(*status) + "; see " + c.logPath();
          spdlog::error("{}", failure);
          stopping = true;
        }
      } else if (c.running()) {
        any = true;
      }
    }
    if (!any) break;
    if (g_interrupted && !stopping) {
      spdlog::warn("interrupted: stopping every service (the tables so far are kept)");
      stopping = true;
    }
    if (stopping) {  // upstream first: the source, then the tracker, the optimiser, the mapper
      for (const char* name : {"player", "tracker", "optimiser", "mapper"}) {
        const auto it = std::find_if(children.begin(), children.end(), [&](const ChildProcess& c) { return c.name() == name; });
        if (it == children.end() || !it->running()) continue;
        auto& t = terminated[static_cast<size_t>(it - children.begin())];
        if (!t) {
          it->terminate();
          t = Clock::now();
        } else if (since(*t) > kStopGraceS) {
          it->kill();
        }
        break;
      }
    }
    if (Clock::now() >= next_rss) {
      next_rss += std::chrono::seconds(1);
      for (const auto& c : children)
        if (const auto mb = c.rssMb()) rss << fmt::format("{:.1f},{},{:.1f}\n", since(zero), c.name(), *mb);
      rss.flush();
    }
    if (Clock::now() >= next_table) {
      next_table += std::chrono::seconds(static_cast<int>(kTableEveryS));
      writeTables(o, -1, header);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  // End of run: from the source's last frame (its "lingering" heartbeat; else its exit) to the last service's exit.
  const std::optional<Clock::time_point> stream_end = tiers && tiers->streamEnd() ? tiers->streamEnd() : source_done;
  tiers.reset();
  rss.close();
  removeFrameRing(config.getString("transport.segment"));
  store::KeyframeStore::remove(config.getString("mapper.store_segment"));
  const double end_of_run = stream_end && source_done && failure.empty() && !g_interrupted ? since(*stream_end) : -1;
  std::ofstream(o.out + "/longrun_end_of_run_s.txt") << end_of_run << "\n";
  writeTables(o, end_of_run, header);
  std::ifstream summary(o.out + "/summary.txt");
  std::cout << summary.rdbuf();
  spdlog::info("tables in {}: longrun.csv, summary.txt, longrun_*.svg", o.out);
  if (!failure.empty()) {
    spdlog::error("{}", failure);
    return 1;
  }
  return g_interrupted ? 130 : 0;
}

}  // namespace

int benchLongrunCommand(int argc, char** argv) {
  ArgParser args(argv[0], "A long scan through the real services (tracker, optimiser, mapper), measured per minute.");
  args.option("scene", "a synthetic scene rendered on the fly (rekon-synth-source)", "building")
      .option("dataset", "a TUM dataset played by rekon-player instead of --scene")
      .option("out", "output folder (new or empty)")
      .option("minutes", "minutes of frames at 30 Hz (the building walks on as long as asked)", "0")
      .option("frames", "frames instead of --minutes (0 = the scene's default for --laps, the whole dataset)", "0")
      .option("laps", "laps of the scene's walk when neither --minutes nor --frames is given", "1")
      .option("pace", "live (30 Hz; what the consumers are not ready for is dropped) or max (unpaced)", "live")
      .option("bucket-s", "seconds per row of longrun.csv and per point of the plots", "60")
      .option("render-threads", "threads that ray cast each frame of --scene", "1")
      .option("tabulate", "only write the tables, plots and summary of this earlier run folder again")
      .option("config", "YAML config laid over config/default.yaml")
      .repeated("set", "override one config key, e.g. --set mapper.host_mb=512")
      .examples("rekon bench longrun --out out/longrun60 --minutes 60          # issue 49's hour (about 70 min)\n"
                "rekon bench longrun --out out/longrun10 --minutes 10\n"
                "rekon bench longrun --dataset out/room --out out/room_longrun --bucket-s 5");
  if (!args.parse(argc, argv)) return 0;
  Options o;
  if (!args.get("tabulate").empty()) {  // the tables of a run folder again (a stopped run's, or after a change here)
    o.out = args.get("tabulate");
    o.bucket_s = args.getDouble("bucket-s");
    if (!(o.bucket_s >= 1)) throw Error("--bucket-s must be 1 or more");
    if (!fs::exists(fs::path(o.out) / "config.yaml")) throw Error(o.out + " holds no rekon bench longrun run (no config.yaml)");
    double end_of_run = -1;
    std::ifstream(o.out + "/longrun_end_of_run_s.txt") >> end_of_run;
    writeTables(o, end_of_run, "rekon bench longrun --tabulate " + o.out + fmt::format(", buckets of {:.0f} s", o.bucket_s));
    std::ifstream summary(o.out + "/summary.txt");
    std::cout << summary.rdbuf();
    return 0;
  }
  o.scene = args.get("scene");
  o.dataset = args.get("dataset");
  o.out = args.get("out");
  o.pace = args.get("pace");
  o.config_file = args.get("config");
  o.sets = args.all("set");
  o.laps = args.getInt("laps");
  o.render_threads = args.getInt("render-threads");
  o.bucket_s = args.getDouble("bucket-s");
  const double minutes = args.getDouble("minutes");
  o.frames = args.getInt("frames");
  if (o.out.empty()) throw Error("rekon bench longrun needs --out DIR; see --help");
  if (o.pace != "live" && o.pace != "max") throw Error("--pace '" + o.pace + "' must be live or max");
  if (minutes != 0 && o.frames != 0) throw Error("give --minutes or --frames, not both");
  if (!(minutes >= 0 && minutes <= 600)) throw Error("--minutes must lie in [0, 600]");
  if (minutes > 0) o.frames = static_cast<int>(std::lround(minutes * 1800.0));
  if (o.frames < 0) throw Error("--frames must be 0 or more");
  if (!(o.bucket_s >= 1)) throw Error("--bucket-s must be 1 or more");
  if (o.render_threads < 1 || o.render_threads > 64) throw Error("--render-threads must lie in [1, 64]");
  if (!o.dataset.empty() && !fs::exists(fs::path(o.dataset) / "rgb.txt"))
    throw Error("--dataset " + o.dataset + " has no rgb.txt; give a TUM dataset folder");
  if (o.dataset.empty()) synth::Scene::make(o.scene);  // an unknown scene: one line naming the choices
  return run(o);
}

}  // namespace rekon::longrun
