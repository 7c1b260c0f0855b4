// `rekon chaos`: how far kill -9 moves a run. A dataset at its recorded rate,
// once as it is and once with a random service (seeded) killed every few
// seconds; prints kills, restarts, poses, ATE and the mesh's CORR against the
// uninterrupted run (aligned by their trajectories), writes them to
// OUT/chaos.json, and exits 1 when an outcome is out of its bounds. With
// --same-frames a third run plays, uninterrupted, only the frames the killed
// run has poses for: what the restarts cost beyond the frames lost in outages.
#include <signal.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <regex>
#include <sstream>
#include <thread>

#include "launcher.hpp"
#include "process.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/json.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/eval/surface_eval.hpp"
#include "rekon/eval/trajectory_eval.hpp"

namespace rekon {
namespace fs = std::filesystem;
namespace {

using Clock = std::chrono::steady_clock;
std::atomic<bool> g_chaos_interrupted{false};
void onChaosInterrupt(int) { g_chaos_interrupted.store(true); }

struct Bounds {
  double min_poses = 0.95;     // of the uninterrupted run's
  double max_ate_ratio = 1.5;  // ATE at most this times the uninterrupted run's ...
  double ate_slack_m = 0.0005; // ... plus this
  double max_corr_m = 0.002;   // the mesh against the uninterrupted run's
};

struct ChaosOptions {
  std::string dataset, out, baseline;
  double every_min_s = 3, every_max_s = 6;
  uint64_t seed = 1;
  std::vector<std::string> victims;
  std::vector<std::string> sets;
  bool same_frames = false;
  Bounds bounds;
};

struct Kill {
  double at_s;
  std::string service;
  int pid;
};

// What one run left: its exit status, the kills made in it, the restarts
// rekon run counted (stats.json), its poses and ATE (-1 without ground truth).
struct Outcome {
  std::string folder;
  int rc = -1;
  std::vector<Kill> kills;
  std::map<std::string, long long> restarts;
  size_t poses = 0;
  double ate_m = -1;
};

// Each service's newest pid, from rekon run's "started/restarted rekon-X (pid N)" lines.
std::map<std::string, int> servicePids(const std::string& run_log) {
  static const std::regex started(R"((?:re)?started rekon-([a-z_]+) \(pid ([0-9]+)\))");
  std::map<std::string, int> pids;
  std::ifstream in(run_log);
  std::smatch m;
  for (std::string line; std::getline(in, line);)
    if (std::regex_search(line, m, started)) pids[m[1]] = std::stoi(m[2]);
  return pids;
}

size_t poseCount(const std::string& trajectory) {
  std::ifstream in(trajectory);
  size_t n = 0;
  for (std::string l; std::getline(in, l);) n += !l.empty() && l[0] != '#';
  return n;
}

// SIGKILL to one of the victims running now, chosen by `rng`; nullopt when
// none runs, or when only one service of the run still runs: the last one
// standing has finished peers, which its restart waits lifecycle.silence_s
// (5 s) to stop hearing, and kills every second kept a restarted player from
// ever ending the run (the room's chaos test, 215 kills until rekon run's
// 240 s timeout). tests/faults covers that kill on its own.
std::optional<Kill> killOne(const std::vector<std::string>& victims, const std::string& run_log, std::mt19937_64& rng,
                            double at_s) {
  const auto pids = servicePids(run_log);
  const auto running = [](int pid) { return ::kill(pid, 0) == 0; };
  std::vector<std::pair<std::string, int>> alive;
  for (const auto& v : victims) {
    const auto it = pids.find(v);
    if (it != pids.end() && running(it->second)) alive.emplace_back(*it);
  }
  const auto services_running = std::count_if(pids.begin(), pids.end(), [&](const auto& p) { return running(p.second); });
  if (alive.empty() || services_running < 2) return std::nullopt;
  const auto& [service, pid] = alive[std::uniform_int_distribution<size_t>(0, alive.size() - 1)(rng)];
  if (::kill(pid, SIGKILL) != 0) return std::nullopt;
  spdlog::info("chaos: killed rekon-{} (pid {}) at {:.1f} s", service, pid, at_s);
  return Kill{at_s, service, pid};
}

// What the run in o.folder left: its poses, their ATE against the
// dataset's ground truth (when it has one), the restarts rekon run counted.
void readResults(Outcome& o, const std::string& dataset) {
  o.poses = poseCount(o.folder + "/trajectory.txt");
  const fs::path gt = fs::path(dataset) / "groundtruth.txt";
  if (fs::exists(gt) && o.poses >= 2) {
    o.ate_m = eval::evaluateTrajectory(readTumTrajectory(gt.string()), readTumTrajectory(o.folder + "/trajectory.txt"))
                  .ate_rmse_m;
  }
  try {
    const YAML::Node restarts = YAML::LoadFile(o.folder + "/stats.json")["restarts"];
    for (const auto& kv : restarts) o.restarts[kv.first.as<std::string>()] = kv.second.as<long long>();
  } catch (const YAML::Exception&) {
  }
}

// One `rekon run` of `dataset` at its recorded rate into `folder`; with
// `kills` (the schedule's generator), one of the victims killed every
// every_min_s..every_max_s seconds. Only the run with kills draws from it, so
// a seed's schedule is the same with and without --baseline. `extra_sets`
// come after the user's.
Outcome runOnce(const ChaosOptions& opt, const std::string& dataset, const std::string& folder, std::mt19937_64* kills,
                const std::vector<std::string>& extra_sets = {}) {
  const bool with_kills = kills != nullptr;
  Outcome o;
  o.folder = folder;
  std::vector<std::string> args = {"run", "--dataset", dataset, "--out", folder, "--force", "--set", "player.rate=1"};
  for (const auto& s : opt.sets) args.insert(args.end(), {"--set", s});
  for (const auto& s : extra_sets) args.insert(args.end(), {"--set", s});
  // Every kill is restarted: the bound is the outcome, not a count of restarts.
  if (with_kills)
    args.insert(args.end(), {"--set", fmt::format("run.restart=[{}]", fmt::join(opt.victims, ",")), "--set", "run.max_restarts=1000"});
  const std::string log = folder + ".log";
  fs::remove(log);
  ChildProcess run("run", executableDir() + "/rekon", args, log);
  run.start();
  spdlog::info("{} run: rekon run into {} (log {})", with_kills ? "chaos" : "uninterrupted", folder, log);
  std::uniform_real_distribution<double> gap(opt.every_min_s, opt.every_max_s);
  const auto next_gap = [&] {
    return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(gap(*kills)));
  };
  const auto start = Clock::now();
  auto next_kill = with_kills ? start + next_gap() : start;
  bool terminated = false;
  while (true) {
    if (const auto status = run.poll()) {
      o.rc = *status;
      break;
    }
    if (g_chaos_interrupted.load() && !terminated) {
      run.terminate();  // rekon run stops its services in order
      terminated = true;
    }
    if (with_kills && !terminated && Clock::now() >= next_kill) {
      const double at = std::chrono::duration<double>(Clock::now() - start).count();
      if (auto k = killOne(opt.victims, log, *kills, at)) o.kills.push_back(*k);
      next_kill += next_gap();
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  readResults(o, dataset);
  return o;
}

// The dataset's frames that `run` has poses for, as a dataset of their own
// in `out` (TumDataset::writeSubset): the frames its outages cost are
// missing from it, and with them the gaps the tracker saw.
void writeFramesWithPoses(const std::string& dataset, const std::string& run, const std::string& out) {
  std::vector<double> posed;
  for (const auto& stamped : readTumTrajectory(run + "/trajectory.txt")) posed.push_back(stamped.timestamp);
  std::sort(posed.begin(), posed.end());
  constexpr double kSameStamp = 1e-5;  // trajectory.txt's timestamps have 6 decimals
  const TumDataset all(dataset);
  const size_t kept = all.writeSubset(out, [&](size_t i) {
    const auto it = std::lower_bound(posed.begin(), posed.end(), all.timestamp(i) - kSameStamp);
    return it != posed.end() && *it <= all.timestamp(i) + kSameStamp;
  });
  if (kept == 0) throw Error(run + "/trajectory.txt has no pose of a frame of " + dataset + ": nothing to play again");
  spdlog::info("{}: the {} of {} frames the chaos run has poses for", out, kept, all.size());
}

// The uninterrupted run of the frames `killed` has poses for (--same-frames);
// rc -1 when there are none to play (the killed run left no trajectory).
Outcome runSameFrames(const ChaosOptions& opt, const Outcome& killed) {
  const std::string dataset = opt.out + "/same_frames_dataset", folder = opt.out + "/same_frames";
  try {
    writeFramesWithPoses(opt.dataset, killed.folder, dataset);
  } catch (const Error& e) {
    spdlog::error("no run of the same frames: {}", e.what());
    Outcome none;
    none.folder = folder;
    return none;
  }
  // The subset holds only the frames to play: the user's frame range is in it already.
  return runOnce(opt, dataset, folder, nullptr, {"player.first_frame=0", "player.max_frames=0"});
}

// "7 (player 2, tracker 1, ...)": how many, and how many of each service.
std::string countsByService(const std::map<std::string, long long>& by_service) {
  long long total = 0;
  std::vector<std::string> parts;
  for (const auto& [service, n] : by_service) total += n, parts.push_back(fmt::format("{} {}", service, n));
  return parts.empty() ? "0" : fmt::format("{} ({})", total, fmt::join(parts, ", "));
}

std::map<std::string, long long> killsByService(const std::vector<Kill>& kills) {
  std::map<std::string, long long> by;
  for (const auto& k : kills) ++by[k.service];
  return by;
}

std::string ateText(const Outcome& o) {
  if (o.poses < 2) return "n/a (no trajectory)";
  return o.ate_m < 0 ? "n/a (no groundtruth.txt)" : fmt::format("{:.2f} mm", 1e3 * o.ate_m);
}

// The outcomes out of their bounds, one line each (none: the run held).
std::vector<std::string> outOfBounds(const Outcome& clean, const Outcome& chaos, double corr_m, const Bounds& b) {
  std::vector<std::string> out;
  if (chaos.rc != 0) out.push_back(fmt::format("the chaos run exited with {} (see {}.log)", chaos.rc, chaos.folder));
  const double min_poses = b.min_poses * static_cast<double>(clean.poses);
  if (static_cast<double>(chaos.poses) < min_poses)
    out.push_back(fmt::format("{} poses, fewer than {:.0f} ({:.0f} % of the uninterrupted run's {})", chaos.poses, min_poses,
                              100 * b.min_poses, clean.poses));
  if (clean.ate_m >= 0 && chaos.ate_m > b.max_ate_ratio * clean.ate_m + b.ate_slack_m)
    out.push_back(fmt::format("ATE {:.3f} mm, above {:.1f} x {:.3f} + {:.1f} mm", 1e3 * chaos.ate_m, b.max_ate_ratio,
                              1e3 * clean.ate_m, 1e3 * b.ate_slack_m));
  if (!(corr_m <= b.max_corr_m))
    out.push_back(fmt::format("the mesh is {:.3f} mm (CORR) from the uninterrupted run's, above {:.1f} mm", 1e3 * corr_m,
                              1e3 * b.max_corr_m));
  return out;
}

// The killed run against the uninterrupted run of the same frames (--same-frames).
struct SameFrames {
  Outcome run;
  double trajectory_rmse_m = -1;  // the killed run's trajectory against this run's, rigidly aligned
  double corr_m = -1;             // the killed run's mesh against this run's
};

void writeJson(const ChaosOptions& opt, const Outcome& clean, const Outcome& chaos, double corr_m,
               const std::optional<SameFrames>& same, const std::vector<std::string>& failures) {
  JsonObject kills;
  for (const auto& [service, n] : killsByService(chaos.kills)) kills.set(service, n);
  JsonObject restarts;
  for (const auto& [service, n] : chaos.restarts) restarts.set(service, n);
  JsonObject j;
  j.set("dataset", opt.dataset)
      .set("seed", static_cast<long long>(opt.seed))
      .set("every_min_s", opt.every_min_s)
      .set("every_max_s", opt.every_max_s)
      .set("kills", static_cast<long long>(chaos.kills.size()))
      .set("kills_by_service", kills)
      .set("restarts_by_service", restarts)
      .set("exit_status", chaos.rc)
      .set("poses_uninterrupted", clean.poses)
      .set("poses", chaos.poses)
      .set("ate_uninterrupted_m", clean.ate_m)
      .set("ate_m", chaos.ate_m)
      .set("corr_vs_uninterrupted_m", corr_m)
      .set("within_bounds", failures.empty());
  if (same) {
    j.set("same_frames_exit_status", same->run.rc)
        .set("same_frames_poses", same->run.poses)
        .set("same_frames_ate_m", same->run.ate_m)
        .set("trajectory_rmse_vs_same_frames_m", same->trajectory_rmse_m)
        .set("corr_vs_same_frames_m", same->corr_m);
  }
  j.save(opt.out + "/chaos.json");
}

// How far run `a` is from run `b`: its trajectory's RMSE after the rigid
// alignment onto `b`'s, and the CORR of its mesh, moved by that alignment,
// against `b`'s (as docs/faults.md compares two runs): what differs in
// shape, not a shift of the whole map.
struct RunDistance {
  double trajectory_rmse_m;
  double corr_m;
};
RunDistance runDistance(const std::string& a, const std::string& b) {
  const eval::TrajectoryErrors aligned =
      eval::evaluateTrajectory(readTumTrajectory(b + "/trajectory.txt"), readTumTrajectory(a + "/trajectory.txt"));
  Mesh mesh = readPly(a + "/mesh.ply");
  const Eigen::Isometry3f to_b = aligned.alignment.cast<float>();
  for (auto& v : mesh.vertices) v = to_b * v;
  return {aligned.ate_rmse_m, eval::evaluateSurface(mesh, readPly(b + "/mesh.ply")).corr_m};
}

// `killed` against the uninterrupted run of the frames it has poses for.
SameFrames compareWithSameFrames(const ChaosOptions& opt, const Outcome& killed) {
  SameFrames same{runSameFrames(opt, killed)};
  if (same.run.rc != 0) return same;
  try {
    const RunDistance d = runDistance(killed.folder, same.run.folder);
    same.trajectory_rmse_m = d.trajectory_rmse_m;
    same.corr_m = d.corr_m;
  } catch (const Error& e) {
    spdlog::error("the run of the same frames could not be compared: {}", e.what());
  }
  return same;
}

// One line of the table: a name, then a value per run (a longer one pushes the next on).
void printRow(const std::string& name, const std::vector<std::string>& values) {
  fmt::print("{:<34}", name);
  for (const auto& v : values) fmt::print("{:<{}}", v, std::max<size_t>(26, v.size() + 2));
  fmt::print("\n");
}

// The runs side by side: the uninterrupted one, the killed one and (--same-frames) the same frames'.
void printTable(const ChaosOptions& opt, const Outcome& clean, const Outcome& killed, double corr_m,
                const std::optional<SameFrames>& same) {
  const auto row = [&](const std::string& name, const std::string& a, const std::string& b, const std::string& c) {
    printRow(name, same ? std::vector<std::string>{a, b, c} : std::vector<std::string>{a, b});
  };
  const auto mm = [](double m) { return m < 0 ? std::string("n/a") : fmt::format("{:.3f} mm", 1e3 * m); };
  fmt::print("\n");
  row("", "uninterrupted", fmt::format("killed every {:g}-{:g} s", opt.every_min_s, opt.every_max_s),
      "uninterrupted, same frames");
  row("exit status", std::to_string(clean.rc), std::to_string(killed.rc), same ? std::to_string(same->run.rc) : "");
  row("kills (seed " + std::to_string(opt.seed) + ")", "-", countsByService(killsByService(killed.kills)), "-");
  row("restarts", "-", countsByService(killed.restarts), "-");
  row("poses (frames tracked)", std::to_string(clean.poses), std::to_string(killed.poses),
      same ? std::to_string(same->run.poses) : "");
  row("ATE", ateText(clean), ateText(killed), same ? ateText(same->run) : "");
  row("mesh CORR vs the uninterrupted", "-", mm(corr_m), "-");
  if (same) {
    row("trajectory vs the same frames", "-", mm(same->trajectory_rmse_m) + " (RMSE)", "-");
    row("mesh CORR vs the same frames", "-", mm(same->corr_m), "-");
  }
}

int chaos(const ChaosOptions& opt) {
  createOutputFolder(opt.out);
  signal(SIGINT, onChaosInterrupt);
  signal(SIGTERM, onChaosInterrupt);
  Outcome clean;
  if (opt.baseline.empty()) {
    clean = runOnce(opt, opt.dataset, opt.out + "/uninterrupted", nullptr);
    if (clean.rc != 0 && !g_chaos_interrupted.load())
      throw Error(fmt::format("the uninterrupted run failed (exit {}): see {}/uninterrupted.log; fix that first", clean.rc, opt.out));
  } else {
    clean.folder = opt.baseline;
    clean.rc = 0;
    readResults(clean, opt.dataset);
  }
  if (g_chaos_interrupted.load()) return 130;
  std::mt19937_64 rng(opt.seed);
  const Outcome killed = runOnce(opt, opt.dataset, opt.out + "/chaos", &rng);
  if (g_chaos_interrupted.load()) return 130;
  std::optional<SameFrames> same;
  if (opt.same_frames) {
    same = compareWithSameFrames(opt, killed);
    if (g_chaos_interrupted.load()) return 130;
  }
  double corr_m = std::numeric_limits<double>::infinity();
  try {
    corr_m = runDistance(killed.folder, clean.folder).corr_m;
  } catch (const Error& e) {
    spdlog::error("the meshes could not be compared: {}", e.what());
  }
  std::vector<std::string> failures = outOfBounds(clean, killed, corr_m, opt.bounds);
  if (same && same->run.rc != 0)
    failures.push_back(same->run.rc < 0 ? std::string("no run of the same frames (see the error above)")
                                        : fmt::format("the run of the same frames exited with {} (see {}.log)",
                                                      same->run.rc, same->run.folder));
  writeJson(opt, clean, killed, corr_m, same, failures);

  printTable(opt, clean, killed, corr_m, same);
  for (const auto& f : failures) fmt::print("out of bounds: {}\n", f);
  fmt::print("{}; {}/chaos.json\n", failures.empty() ? "within bounds" : "OUT OF BOUNDS", opt.out);
  return failures.empty() ? 0 : 1;
}

// "3-6" or "4": the seconds between kills.
std::pair<double, double> parseEvery(const std::string& text) {
  const auto dash = text.find('-');
  try {
    const double lo = std::stod(text.substr(0, dash)), hi = dash == std::string::npos ? lo : std::stod(text.substr(dash + 1));
    if (lo > 0 && hi >= lo) return {lo, hi};
  } catch (const std::exception&) {
  }
  throw Error("--every '" + text + "' must be seconds between kills, e.g. 4 or 3-6");
}

}  // namespace

int chaosCommand(int argc, char** argv) {
  ArgParser args("rekon chaos", "Runs a dataset at its recorded rate twice, once as it is and once killing a random "
                                "service (kill -9, seeded) every few seconds; compares the two and exits 1 when the "
                                "killed run is out of its bounds.");
  args.option("dataset", "TUM RGB-D folder (required); with groundtruth.txt the ATE of both runs is shown")
      .option("out", "output folder (required): uninterrupted/, chaos/, their logs and chaos.json")
      .option("every", "seconds between kills, a range drawn from", "3-6")
      .option("seed", "seed of the kills' times and victims", "1")
      .option("services", "the services to kill, comma-separated (default: those in run.restart)")
      .option("baseline", "an uninterrupted run folder of the same dataset to compare with, instead of running one")
      .option("min-poses", "bound: poses at least this fraction of the uninterrupted run's", "0.95")
      .option("max-ate-ratio", "bound: ATE at most this times the uninterrupted run's plus --ate-slack-mm", "1.5")
      .option("ate-slack-mm", "bound: see --max-ate-ratio", "0.5")
      .option("max-corr-mm", "bound: the mesh's CORR against the uninterrupted run's mesh", "2")
      .flag("same-frames", "then run, uninterrupted, only the frames the killed run has poses for, and compare: what "
                           "the restarts cost beyond the frames lost in outages (OUT/same_frames)")
      .repeated("set", "a config key for both runs, e.g. --set mapper.kappa=10")
      .examples("rekon chaos --dataset out/room --out out/chaos_room\n"
                "rekon chaos --dataset ../shared/data/7scenes_loop_1000 --out out/chaos_7s --every 10 --seed 7");
  if (!args.parse(argc, argv)) return 0;
  setupLogging("chaos", "info");
  ChaosOptions opt;
  opt.dataset = args.get("dataset");
  opt.out = args.get("out");
  if (opt.dataset.empty() || opt.out.empty()) throw Error("rekon chaos needs --dataset DIR and --out DIR; see rekon chaos --help");
  if (!fs::is_directory(opt.dataset)) throw Error(opt.dataset + ": dataset folder not found");
  opt.dataset = fs::canonical(opt.dataset).string();
  std::tie(opt.every_min_s, opt.every_max_s) = parseEvery(args.get("every"));
  opt.seed = static_cast<uint64_t>(std::stoull(args.get("seed")));
  opt.baseline = args.get("baseline");
  if (!opt.baseline.empty() && !fs::exists(opt.baseline + "/mesh.ply"))
    throw Error("--baseline " + opt.baseline + " holds no mesh.ply: give a finished rekon run folder of the same dataset");
  opt.sets = args.all("set");
  opt.same_frames = args.flagSet("same-frames");
  std::stringstream services(args.get("services"));
  for (std::string s; std::getline(services, s, ',');)
    if (!s.empty()) opt.victims.push_back(s);
  if (!args.has("services")) opt.victims = Config::load("", opt.sets).getStringList("run.restart");
  if (opt.victims.empty()) throw Error("--services names no service to kill");
  opt.bounds = {args.getDouble("min-poses"), args.getDouble("max-ate-ratio"), 1e-3 * args.getDouble("ate-slack-mm"),
                1e-3 * args.getDouble("max-corr-mm")};
  return chaos(opt);
}

}  // namespace rekon
