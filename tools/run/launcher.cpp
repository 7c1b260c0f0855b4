#include "launcher.hpp"

#include <signal.h>
#include <spdlog/spdlog.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <set>
#include <thread>

#include "process.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_ring.hpp"
#include "rekon/common/json.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/report/run_report.hpp"
#include "rekon/store/keyframe_store.hpp"
#include "rekon/synth/synth.hpp"

namespace rekon {
namespace fs = std::filesystem;
namespace {

using Clock = std::chrono::steady_clock;
std::atomic<bool> g_interrupted{false};
void onInterrupt(int) { g_interrupted.store(true); }

// A stats file written by a service, as JSON text (services write JSON; YAML reads it).
std::string jsonOf(const YAML::Node& node) {
  if (node.IsMap()) {
    JsonObject o;
    for (const auto& kv : node) o.setRaw(kv.first.as<std::string>(), jsonOf(kv.second));
    return o.str(0);
  }
  if (node.IsScalar()) {
    const std::string s = node.Scalar();
    if (node.Tag() == "!") return jsonString(s);  // a quoted string in the file stays a string
    try {
      size_t used = 0;
      std::stod(s, &used);
      if (used == s.size()) return s;
    } catch (const std::exception&) {
    }
    if (s == "true" || s == "false" || s == "null") return s;
    return jsonString(s);
  }
  return "null";
}

// Seconds a service gets between SIGTERM and SIGKILL when the run stops.
constexpr int kStopGraceS = 10;

// Stopping order: upstream first, so that downstream services still receive
// what the upstream ones send while finishing.
int stopRank(const std::string& service) {
  static const std::vector<std::string> order = {"player", "replay", "tracker", "optimiser", "mapper"};
  const auto it = std::find(order.begin(), order.end(), service);
  return static_cast<int>(it - order.begin());
}

// run.restart / run.max_restarts. Only services that recover their state can
// be restarted: the mapper (keyframe store) and the optimiser (tracker replay).
std::pair<std::set<std::string>, int> restartPolicy(const Config& config) {
  std::set<std::string> services;
  for (const auto& s : config.getStringList("run.restart")) {
    if (s != "mapper" && s != "optimiser") {
      throw Error("run.restart lists '" + s + "'; only mapper and optimiser can be restarted (they recover from the "
                  "keyframe store and the tracker's replay); remove it");
    }
    services.insert(s);
  }
  const int max_restarts = config.getInt("run.max_restarts");
  if (max_restarts < 0) throw Error("run.max_restarts must be 0 or more (restarts per service)");
  return {services, max_restarts};
}

struct RunOptions {
  std::string dataset, out, config_file;
  std::vector<std::string> sets;
  bool report = false;
};

int launch(const RunOptions& opt) {
  Config config = Config::load(opt.config_file, opt.sets);
  setupLogging("run", config.getString("log.level"));
  createOutputFolder(opt.out);
  const std::string out = fs::canonical(opt.out).string();
  const std::string bin = executableDir();

  // One frame ring and one keyframe store per run, so runs side by side never meet.
  const std::string segment = config.getString("transport.segment") + "_" + std::to_string(getpid());
  config.set("transport.segment", segment);
  const std::string store_segment = config.getString("mapper.store_segment") + "_" + std::to_string(getpid());
  config.set("mapper.store_segment", store_segment);
  const auto [restartable, max_restarts] = restartPolicy(config);

  std::vector<std::string> services;
  for (const auto& s : config.getStringList("run.services")) {
    if (fs::exists(bin + "/rekon-" + s)) services.push_back(s);
    else spdlog::warn("rekon-{} is not part of this build; running without it", s);
  }
  if (std::find(services.begin(), services.end(), "player") == services.end()) {
    throw Error("run.services has no player; rekon run needs a frame source");
  }
  // The player waits only for consumers that this run starts.
  std::vector<std::string> wait_for;
  for (const auto& s : config.getStringList("player.wait_for")) {
    if (std::find(services.begin(), services.end(), s) != services.end()) wait_for.push_back(s);
  }
  std::string list = "[";
  for (size_t i = 0; i < wait_for.size(); ++i) list += (i ? ", " : "") + wait_for[i];
  config.set("player.wait_for", list + "]");
  const std::string config_path = out + "/config.yaml";
  config.save(config_path);
  // The report and the evaluation find the dataset (and its ground truth) from here.
  std::ofstream(out + "/dataset.txt") << fs::canonical(opt.dataset).string() << "\n";

  // Consumers first; the player waits for their heartbeats before it sends.
  std::stable_partition(services.begin(), services.end(), [](const std::string& s) { return s != "player"; });
  std::vector<ChildProcess> children;
  for (const auto& s : services) {
    std::vector<std::string> args = {"--config", config_path, "--out", out};
    if (s == "player") args.insert(args.end(), {"--dataset", opt.dataset});
    children.emplace_back(s, bin + "/rekon-" + s, args, out + "/" + s + ".log");
  }

  signal(SIGINT, onInterrupt);
  signal(SIGTERM, onInterrupt);
  const auto start = Clock::now();
  int exit_code = 0;
  std::string failure;
  try {
    for (auto& c : children) {
      fs::remove(c.logPath());
      c.start();
      spdlog::info("started rekon-{} (pid {}), log {}", c.name(), c.pid(), c.logPath());
    }
  } catch (const Error& e) {
    failure = e.what();
  }
  const double shutdown_timeout = config.getDouble("run.shutdown_timeout_s");
  std::optional<Clock::time_point> player_done;
  // Stopping goes downstream, one service at a time: each gets SIGTERM once
  // the one before it has exited, so that the optimiser's last graph update
  // still reaches the mapper and everything produced so far is written.
  std::vector<size_t> stop_order(children.size());
  for (size_t i = 0; i < children.size(); ++i) stop_order[i] = i;
  std::stable_sort(stop_order.begin(), stop_order.end(),
                   [&](size_t a, size_t b) { return stopRank(children[a].name()) < stopRank(children[b].name()); });
  std::vector<std::optional<Clock::time_point>> terminated_at(children.size());
  std::vector<bool> killed(children.size(), false);
  bool stopping = false;
  auto stopAll = [&] { stopping = true; };
  if (!failure.empty()) stopAll();

  std::ofstream rss(out + "/rss.csv");
  rss << "seconds,service,rss_mb\n";
  auto next_rss = Clock::now();
  while (true) {
    bool any_running = false;
    for (auto& c : children) {
      const auto st = c.poll();
      if (!st) {
        any_running = true;
        continue;
      }
      if (c.name() == "player" && *st == 0 && !player_done) {
        player_done = Clock::now();
        spdlog::info("the player has finished; waiting for the services to finish");
      }
      if (*st == 0 || stopping || g_interrupted.load()) continue;
      const std::string how = "rekon-" + c.name() + " " + describeExit(*st);
      if (restartable.count(c.name()) && c.restarts() < max_restarts) {
        spdlog::warn("{}; restarting it ({} of at most {} restarts, run.max_restarts)", how, c.restarts() + 1, max_restarts);
        std::vector<std::string> extra;
        // The mapper continues from its keyframe store; the optimiser rebuilds from the tracker's replay.
        if (c.name() == "mapper") extra = {"--set", "mapper.resume=true"};
        try {
          c.restart(extra);
          spdlog::info("restarted rekon-{} (pid {})", c.name(), c.pid());
          any_running = true;
          continue;
        } catch (const Error& e) {
          spdlog::error("{}", e.what());
        }
      }
      if (failure.empty()) {
        failure = how + (restartable.count(c.name()) ? " (restarted " + std::to_string(c.restarts()) + " times already)" : "") +
                  "; the run was stopped, outputs so far are in " + out + "; see " + c.logPath();
        spdlog::error("{}", failure);
        stopAll();
      }
    }
    if (!any_running) break;
    if (Clock::now() >= next_rss) {
      next_rss += std::chrono::seconds(1);
      const double t = std::chrono::duration<double>(Clock::now() - start).count();
      for (const auto& c : children) {
        if (const auto mb = c.rssMb()) rss << fmt::format("{:.1f},{},{:.1f}\n", t, c.name(), *mb);
      }
      rss.flush();
    }
    if (g_interrupted.load() && !stopping) {
      spdlog::warn("interrupted: stopping every service (outputs so far are kept)");
      stopAll();
    }
    if (player_done && !stopping && Clock::now() > *player_done + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(shutdown_timeout))) {
      failure = "services did not finish within run.shutdown_timeout_s = " + std::to_string(int(shutdown_timeout)) + " s after the end of the data";
      spdlog::error("{}", failure);
      stopAll();
    }
    if (stopping) {
      for (size_t i : stop_order) {
        ChildProcess& c = children[i];
        if (!c.running()) continue;
        if (!terminated_at[i]) {
          c.terminate();
          terminated_at[i] = Clock::now();
        } else if (!killed[i] && Clock::now() > *terminated_at[i] + std::chrono::seconds(kStopGraceS)) {
          spdlog::error("rekon-{} did not stop within {} s of SIGTERM; killing it", c.name(), kStopGraceS);
          c.kill();
          killed[i] = true;
        }
        break;  // the next one once this one has exited
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  const double wall = std::chrono::duration<double>(Clock::now() - start).count();
  if (removeFrameRing(segment)) spdlog::info("removed the frame ring '{}' left by a stopped player", segment);
  // With its spill files, when a mapper that died for good left it.
  if (store::KeyframeStore::remove(store_segment)) spdlog::info("removed the keyframe store '{}' left by a stopped mapper", store_segment);

  // stats.json: run-level figures plus each service's own stats file.
  JsonObject stats;
  double sequence_seconds = 0;
  long long frames = 0;
  std::vector<std::pair<std::string, std::string>> per_service;
  for (const auto& c : children) {
    const std::string path = out + "/" + c.name() + "_stats.json";
    if (!fs::exists(path)) continue;
    try {
      const YAML::Node node = YAML::LoadFile(path);
      if (c.name() == "player") {
        frames = node["frames"].as<long long>(0);
        sequence_seconds = node["sequence_seconds"].as<double>(0.0);
      }
      per_service.emplace_back(c.name(), jsonOf(node));
    } catch (const YAML::Exception& e) {
      spdlog::warn("{}: unreadable stats ({}); left out of stats.json", path, e.msg);
    }
  }
  stats.set("frames", frames).set("wall_seconds", wall);
  JsonObject restarts;
  for (const auto& c : children) {
    if (c.restarts() > 0) restarts.set(c.name(), static_cast<long long>(c.restarts()));
  }
  stats.setRaw("restarts", restarts.str(0));
  if (sequence_seconds > 0) stats.set("realtime_factor", sequence_seconds / wall);
  for (const auto& [name, json] : per_service) stats.setRaw(name, json);
  stats.save(out + "/stats.json");

  if (opt.report) {
    try {
      report::writeRunReport(out);
    } catch (const Error& e) {
      spdlog::error("report: {}", e.what());  // the run's own outputs stay as they are
    }
  }
  spdlog::info("outputs in {}:", out);
  for (const char* f : {"trajectory.txt", "mesh.ply", "stats.json", "report.html", "config.yaml"}) {
    if (fs::exists(out + "/" + f)) spdlog::info("  {}/{}", out, f);
  }
  spdlog::info("  logs: {}/<service>.log", out);
  if (!failure.empty()) {
    spdlog::error("{}", failure);
    exit_code = 1;
  } else if (g_interrupted.load()) {
    exit_code = 130;
  }
  return exit_code;
}

}  // namespace

int runMain(int argc, char** argv) {
  ArgParser args("rekon run", "Runs the whole pipeline (every service as its own process) on a dataset.");
  args.option("dataset", "TUM RGB-D folder with camera.yaml (required)")
      .option("out", "output folder (required)")
      .option("config", "YAML config laid over config/default.yaml")
      .repeated("set", "override one config key, e.g. --set mapper.voxel_size=0.02")
      .flag("report", "also write report.html (mesh views, trajectory, timing, stats) into --out");
  if (!args.parse(argc, argv)) return 0;
  if (args.get("dataset").empty() || args.get("out").empty()) throw Error("--dataset and --out are required; see rekon run --help");
  if (!fs::is_directory(args.get("dataset"))) throw Error(args.get("dataset") + ": dataset folder not found");
  return launch({args.get("dataset"), args.get("out"), args.get("config"), args.all("set"), args.flagSet("report")});
}

int demoMain(int argc, char** argv) {
  ArgParser args("rekon demo", "Runs the whole pipeline on the built-in default scene (synthetic room) and prints where the outputs are.");
  const fs::path root = fs::path(executableDir()).parent_path().parent_path();
  args.option("out", "output folder", (root / "out" / "demo").string())
      .option("frames", "frames of the synthetic room (0 = its default, 600)", "0")
      .repeated("set", "override one config key, e.g. --set mapper.kappa=10");
  if (!args.parse(argc, argv)) return 0;
  const fs::path out(args.get("out"));
  synth::SequenceOptions scene;
  scene.scene = "room";
  scene.frames = args.getInt("frames");
  const fs::path data = out / ("room_" + std::to_string(scene.frames) + "_data");
  if (!fs::exists(data / "groundtruth.txt")) {
    setupLogging("demo", "info");
    spdlog::info("demo: generating the synthetic room into {} (once)", data.string());
    synth::writeSequence(scene, data.string());
  }
  const int rc = launch({data.string(), out.string(), "", args.all("set"), true});
  if (rc == 0 && fs::exists(out / "trajectory.txt")) {
    spdlog::info("compare with the ground truth: tools/rekon eval traj {} {}", (data / "groundtruth.txt").string(),
                 (out / "trajectory.txt").string());
  }
  if (rc == 0 && fs::exists(out / "mesh.ply")) {
    spdlog::info("and the surface: tools/rekon eval surface {} {}", (out / "mesh.ply").string(), (data / "mesh_gt.ply").string());
  }
  return rc;
}

}  // namespace rekon
