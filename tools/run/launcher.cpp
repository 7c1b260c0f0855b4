#include "launcher.hpp"

#include <signal.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <tuple>
#include <thread>

#include "preflight.hpp"
#include "process.hpp"
#include "progress.hpp"
#include "rekon/camera/recorder.hpp"
#include "rekon/common/camera.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_ring.hpp"
#include "rekon/common/json.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/mapper/store/keyframe_store.hpp"
#include "rekon/mapper/store/session.hpp"
#include "rekon/optimiser/g2o.hpp"
#include "rekon/report/run_report.hpp"
#include "rekon/synth/synth.hpp"
#include "rekon/tracker/keyframe_archive.hpp"
#include "rekon/tracker/params.hpp"

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

// The last error a service logged (its one line saying what went wrong and
// what to do), without the log's time and level prefix; "" when none.
std::string lastErrorLine(const std::string& log_path) {
  std::ifstream in(log_path);
  std::string line, last;
  while (std::getline(in, line)) {
    const auto at = line.find("[error] ");
    if (at != std::string::npos) last = line.substr(at + 8);
  }
  return last;
}

// rekon run --view's optional service: it only listens, and its end never ends the run.
constexpr const char* kViewer = "viewer";

// Seconds a service gets between SIGTERM and SIGKILL when the run stops.
constexpr int kStopGraceS = 10;

// Stopping order: upstream first, so that downstream services still receive
// what the upstream ones send while finishing.
int stopRank(const std::string& service) {
  static const std::vector<std::string> order = {"camera", "realsense", "player", "replay", "tracker", "optimiser", "mapper", "viewer"};
  const auto it = std::find(order.begin(), order.end(), service);
  return static_cast<int>(it - order.begin());
}

// The setting a restarted service is started with, to recover what the
// killed instance had (docs/faults.md): only these services can be restarted.
const std::map<std::string, std::string>& restartSettings() {
  static const std::map<std::string, std::string> settings = {
      {"mapper", "mapper.resume=true"},          // its keyframe store
      {"optimiser", "optimiser.restarted=true"},  // its journal and the tracker's replay
      {"player", "player.restarted=true"},        // where its consumers are
      {"camera", "camera.restarted=true"},        // frame ids after its consumers' newest
      {"tracker", "tracker.restarted=true"},      // its journal and keyframe archive (OUT/tracker_state)
      {"realsense", "realsense.restarted=true"},  // frame ids after its consumers' newest
  };
  return settings;
}

// run.restart / run.max_restarts.
std::pair<std::set<std::string>, int> restartPolicy(const Config& config) {
  std::set<std::string> services;
  for (const auto& s : config.getStringList("run.restart")) {
    if (restartSettings().count(s) == 0) {
      std::vector<std::string> names;
      for (const auto& [name, setting] : restartSettings()) names.push_back(name);
      throw Error(fmt::format("run.restart lists '{}', which cannot be restarted (it cannot recover its state); the "
                              "services that can: {}; remove it",
                              s, fmt::join(names, ", ")));
    }
    services.insert(s);
  }
  const int max_restarts = config.getInt("run.max_restarts");
  if (max_restarts < 0) throw Error("run.max_restarts must be 0 or more (restarts per service)");
  return {services, max_restarts};
}

// What a run is made of, decided before anything starts: the effective
// config (written to config.yaml), this run's own shared-memory names, and
// the children in start order (consumers first: the player waits for them).
struct RunPlan {
  Config config;
  std::string out;
  std::string frame_ring, keyframe_store;  // one of each per run, so runs side by side never meet
  std::set<std::string> restartable;
  int max_restarts = 0;
  std::vector<ChildProcess> children;
  long long total_frames = 0;  // what the player plays; 0: a camera (no end)
  double source_fps = 0;       // the dataset's recorded rate; 0 for a camera
};

// A --camera spec for rekon-realsense (Intel's SDK, a Python service) rather than rekon-camera.
bool isRealSense(const std::string& camera) { return camera.substr(0, camera.find(':')) == "realsense"; }

// The frame source of a run: the player (--dataset), rekon-realsense
// (--camera realsense[:SERIAL]) or the camera (any other --camera).
std::string frameSource(const RunOptions& opt) {
  if (opt.camera.empty()) return "player";
  return isRealSense(opt.camera) ? "realsense" : "camera";
}

// A service that brings the frames: its clean end starts the shutdown clock.
bool isFrameSourceService(const std::string& name) {
  return name == "player" || name == "camera" || name == "realsense";
}

// The services of run.services that this build has, the frame source among
// them: with --camera, rekon-camera takes the player's place.
std::vector<std::string> servicesToRun(const Config& config, const std::string& bin, const std::string& source) {
  std::vector<std::string> services;
  for (auto s : config.getStringList("run.services")) {
    if (s == "player") s = source;
    if (fs::exists(bin + "/rekon-" + s)) services.push_back(s);
    else spdlog::warn("rekon-{} is not part of this build; running without it", s);
  }
  if (std::find(services.begin(), services.end(), source) == services.end()) {
    throw Error("run.services has no player, or rekon-" + source + " is not built; rekon run needs a frame source");
  }
  return services;
}

// --session DIR: a new folder (a session already there is never written
// over), with the run's effective config beside what the services write.
void configureSession(Config& config, const RunOptions& opt) {
  const fs::path dir = fs::absolute(opt.session);
  store::requireNoSession(dir.string());
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw Error("cannot create the session folder " + dir.string() + " (" + ec.message() + ")");
  config.set("session.dir", dir.string());
}

// --continue DIR: every service's part of the session read whole before
// anything starts (a damaged file is one line and the session stays
// untouched): the mapper's keyframes with their checksums, the tracker's
// keyframes, the pose graph; with a dataset, its camera must be the session's.
void configureContinue(Config& config, const RunOptions& opt) {
  const fs::path dir = fs::absolute(opt.continued);
  const store::Session session = store::Session::open(dir.string());
  for (size_t i = 0; i < session.keyframes().size(); ++i) session.load(i);
  const size_t dvo = tracker::loadKeyframes(dir.string(), tracker::trackerParamsFromConfig(config).aligner).size();
  if (fs::exists(dir / "graph.g2o")) optimiser::readG2oFile((dir / "graph.g2o").string());
  if (!opt.dataset.empty()) {
    const Intrinsics k = loadIntrinsics((fs::path(opt.dataset) / "camera.yaml").string());
    if (!sameCamera(k, session.info().camera))
      throw Error(dir.string() + " was made with another camera (" + describeCamera(session.info().camera) + ") than " +
                  opt.dataset + "'s (" + describeCamera(k) + "); continue a session with the camera it was made with");
  }
  spdlog::info("{} session {}: {} KF keyframes, {} DVO keyframes",
               config.getBool("session.localise_only") ? "localising in" : "continuing",
               dir.string(), session.keyframes().size(), dvo);
  config.set("session.dir", dir.string());
  config.set("session.continue", "true");
}

// --localise-only (session.localise_only): the player and the tracker, which
// localises in the session's map and writes trajectory.txt itself. The
// optimiser and the mapper would add to the graph and the map (and write
// them into the session): they do not run, and neither does any other
// service that is not a frame source, the tracker or the viewer.
void planLocalisation(Config& config, const RunOptions& opt, std::vector<std::string>& services) {
  if (opt.localise_only) config.set("session.localise_only", "true");
  if (!config.getBool("session.localise_only")) return;
  if (opt.continued.empty())
    throw Error("session.localise_only localises in a saved session: give it with --continue SESSION "
                "(rekon run --continue SESSION --localise-only)");
  std::erase_if(services, [&](const std::string& s) { return s != frameSource(opt) && s != "tracker"; });
  if (std::find(services.begin(), services.end(), "tracker") == services.end())
    throw Error("--localise-only needs the tracker: add tracker to run.services");
}

// A camera run: the device, its calibration and the recording folder go into
// the effective config (config.yaml says what the run used).
void configureCamera(Config& config, const RunOptions& opt) {
  if (isRealSense(opt.camera)) {  // rekon-realsense: realsense.*, the serial number after "realsense:"
    const size_t colon = opt.camera.find(':');
    if (colon != std::string::npos) config.set("realsense.device", "\"" + opt.camera.substr(colon + 1) + "\"");
    if (!opt.playback.empty()) config.set("realsense.playback", fs::absolute(opt.playback).string());
    if (!opt.calibration.empty()) config.set("realsense.calibration", fs::absolute(opt.calibration).string());
    if (!opt.record.empty()) config.set("realsense.record", fs::absolute(opt.record).string());
    return;
  }
  config.set("camera.device", opt.camera);
  if (!opt.calibration.empty()) config.set("camera.calibration", fs::absolute(opt.calibration).string());
  if (!opt.record.empty()) config.set("camera.record", fs::absolute(opt.record).string());
  // On the terminal, not only in camera.log: the map's scale depends on it.
  if (opt.calibration.empty() && opt.camera.rfind("freenect", 0) == 0)
    spdlog::warn("no --calibration: rekon-camera uses the nominal Kinect v1 calibration (camera.log names it); "
                 "calibrate the camera and pass --calibration camera.yaml for accurate maps");
}

// Everything that can be checked before anything starts or is created;
// returns the frames the player will play and their recorded seconds (0 for a camera).
DatasetSpan checkBeforeStart(const Config& config, const RunOptions& opt) {
  checkConfigValues(config, opt.dataset);
  DatasetSpan span;
  if (!opt.dataset.empty()) span = checkDataset(opt.dataset);
  if (!opt.record.empty()) camera::requireNoRecording(opt.record);  // the camera refused it after every service had started
  if (!opt.camera.empty()) checkCameraSpec(opt.camera, opt.playback, config);  // with --playback: its recording
  const std::vector<std::string> listed = config.getStringList("run.services");
  if (opt.view || std::find(listed.begin(), listed.end(), "viewer") != listed.end()) checkViewerPort(config);
  if (!opt.session.empty()) store::requireNoSession(fs::absolute(opt.session).string());
  if (fs::exists(opt.out)) claimRunFolder(opt.out, opt.force);
  return span;
}

// The frames a run plays (player.first_frame, player.max_frames) and their recorded rate.
void planProgress(RunPlan& plan, const DatasetSpan& span) {
  if (span.frames == 0) return;
  plan.source_fps = span.seconds > 0 ? static_cast<double>(span.frames - 1) / span.seconds : 0.0;
  const long long first = plan.config.getInt("player.first_frame"), most = plan.config.getInt("player.max_frames");
  plan.total_frames = std::max(0LL, span.frames - first);
  if (most > 0) plan.total_frames = std::min<long long>(plan.total_frames, most);
}

RunPlan planRun(const RunOptions& opt) {
  RunPlan plan{Config::load(opt.config_file, opt.sets), "", "", "", {}, 0, {}, 0, 0.0};
  Config& config = plan.config;
  setupLogging("run", config.getString("log.level"));
  std::tie(plan.restartable, plan.max_restarts) = restartPolicy(config);  // a config check: before the dataset's
  planProgress(plan, checkBeforeStart(config, opt));
  const std::string bin = executableDir();
  plan.frame_ring = config.getString("transport.segment") + "_" + std::to_string(getpid());
  config.set("transport.segment", plan.frame_ring);
  plan.keyframe_store = config.getString("mapper.store_segment") + "_" + std::to_string(getpid());
  config.set("mapper.store_segment", plan.keyframe_store);
  // A restartable mapper leaves its store to us (removed below, after the run):
  // one killed after its done_t is restarted into it and only says done again.
  if (plan.restartable.count("mapper") > 0) config.set("mapper.remove_store_at_end", "false");

  const std::string source = frameSource(opt);
  std::vector<std::string> services = servicesToRun(config, bin, source);
  planLocalisation(config, opt, services);
  if (!opt.continued.empty()) configureContinue(config, opt);
  createOutputFolder(opt.out);  // every check passed: a refused run leaves no folder behind
  plan.out = fs::canonical(opt.out).string();
  if (!opt.camera.empty()) configureCamera(config, opt);
  if (!opt.session.empty()) configureSession(config, opt);
  // Behind a source that cannot wait, a busy mapper drops frames rather than
  // holding the tracker's next frames back, loop checks that fall behind
  // take fewer candidates rather than holding the frames back, and the
  // mapping and optimisation threads yield the cores to the source and to tracking.
  if (!opt.camera.empty() || config.getString("player.pacing") == "live") {
    config.set("mapper.when_full", "drop");
    config.set("tracker.loop_when_behind", "fewer");
    config.set("tracker.rewind_wait_s", "0");  // a live source never sends a frame again
    config.set("mapper.rewind_wait_s", "0");
    config.set("mapper.nice", "10");
    config.set("optimiser.nice", "10");
  }
  // The frame source waits only for consumers that this run starts.
  std::string wait_for;
  for (const auto& s : config.getStringList(source + ".wait_for")) {
    if (std::find(services.begin(), services.end(), s) != services.end()) wait_for += (wait_for.empty() ? "" : ", ") + s;
  }
  config.set(source + ".wait_for", "[" + wait_for + "]");
  const std::string config_path = plan.out + "/config.yaml";
  config.save(config_path);
  if (!opt.session.empty()) config.save(config.getString("session.dir") + "/config.yaml");
  // The report and the evaluation find the dataset (and its ground truth) from here.
  if (!opt.dataset.empty()) std::ofstream(plan.out + "/dataset.txt") << fs::canonical(opt.dataset).string() << "\n";

  std::stable_partition(services.begin(), services.end(), [&](const std::string& s) { return s != source; });
  // The viewer only listens: started first, it sees the run from its first message.
  if (opt.view) {
    if (fs::exists(bin + "/rekon-viewer")) services.insert(services.begin(), "viewer");
    else spdlog::warn("rekon-viewer is not part of this build; running without the viewer");
  }
  for (const auto& s : services) {
    std::vector<std::string> args = {"--config", config_path, "--out", plan.out};
    if (s == "player") args.insert(args.end(), {"--dataset", opt.dataset});
    plan.children.emplace_back(s, bin + "/rekon-" + s, args, plan.out + "/" + s + ".log");
  }
  return plan;
}

// Watches the children of a run until every one has ended: restarts those
// that can recover, stops the run on any other death, on Ctrl-C or when the
// services outlast run.shutdown_timeout_s after the player, samples RSS.
class Supervisor {
 public:
  explicit Supervisor(RunPlan& plan)
      : plan_(plan), shutdown_timeout_(plan.config.getDouble("run.shutdown_timeout_s")),
        terminated_at_(plan.children.size()), killed_(plan.children.size(), false), rss_(plan.out + "/rss.csv") {
    // Stopping goes downstream, one service at a time: each gets SIGTERM once
    // the one before it has exited, so that the optimiser's last graph update
    // still reaches the mapper and everything produced so far is written.
    for (size_t i = 0; i < plan.children.size(); ++i) stop_order_.push_back(i);
    std::stable_sort(stop_order_.begin(), stop_order_.end(), [&](size_t a, size_t b) {
      return stopRank(plan.children[a].name()) < stopRank(plan.children[b].name());
    });
    rss_ << "seconds,service,rss_mb\n";
  }

  // Stops at the first child that cannot start (a binary relinked at that
  // moment, a log path that is a folder): the run fails and those started are stopped.
  void startAll() {
    try {
      for (auto& c : plan_.children) {
        std::error_code ec;
        fs::remove(c.logPath(), ec);
        c.start();
        spdlog::info("started rekon-{} (pid {}), log {}", c.name(), c.pid(), c.logPath());
      }
    } catch (const std::exception& e) {
      fail(e.what());
    }
  }

  // One look at every child; false once no service runs any more (the
  // viewer, which only listens, may: serveFinalMap decides how long).
  bool step() {
    bool any_service_running = false;
    for (auto& c : plan_.children) {
      if (const auto status = c.poll()) onEnded(c, *status);
      // Asked after onEnded: a child restarted just now runs too (the last
      // service standing, killed and restarted, once ended the run with exit 0
      // while its restart was still writing the outputs); a child that never
      // started does not (the run would wait for it forever).
      if (c.running()) any_service_running |= c.name() != kViewer;
    }
    if (!any_service_running) return false;
    printViewerUrl();
    sampleRss();
    if (g_interrupted.load() && !stopping_) {
      spdlog::warn("interrupted: stopping every service (outputs so far are kept)");
      stopping_ = true;
    }
    if (source_done_ && !stopping_ && Clock::now() > *source_done_ + std::chrono::duration_cast<Clock::duration>(
                                                                           std::chrono::duration<double>(shutdown_timeout_))) {
      fail("services did not finish within run.shutdown_timeout_s = " + std::to_string(int(shutdown_timeout_)) +
           " s after the end of the data");
    }
    if (stopping_) stopNext();
    return true;
  }

  const std::string& failure() const { return failure_; }

  // The pids of the children running now (a restarted one has a new pid).
  std::set<int> pids() const {
    std::set<int> out;
    for (const auto& c : plan_.children) {
      if (c.running()) out.insert(c.pid());
    }
    return out;
  }

  // After the run (its outputs written): a viewer still running keeps the
  // final map on its page and /mesh.ply for `serve_s` seconds (-1: until
  // Ctrl-C); after a failure or an interrupt it stops at once.
  void serveFinalMap(double serve_s) {
    ChildProcess* viewer = runningViewer();
    if (!viewer) return;
    if (failure_.empty() && !g_interrupted.load() && serve_s != 0) {
      const std::string how_long = serve_s < 0 ? "until Ctrl-C" : fmt::format("for {:.0f} s (viewer.serve_after_run_s)", serve_s);
      spdlog::info("the run has finished; the viewer shows its final map at {} {}", viewer_url_.empty() ? "its URL" : viewer_url_,
                   how_long);
      const auto until = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(serve_s));
      while (!g_interrupted.load() && viewer->running() && (serve_s < 0 || Clock::now() < until)) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
      }
    }
    stopping_ = true;
    while (viewer->running()) {
      viewer->poll();
      stopNext();
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }

 private:
  ChildProcess* runningViewer() {
    for (auto& c : plan_.children) {
      if (c.name() == kViewer && c.running()) return &c;
    }
    return nullptr;
  }

  void fail(const std::string& why) {
    if (!failure_.empty()) return;
    failure_ = why;
    spdlog::error("{}", failure_);
    stopping_ = true;
  }

  // A child that ended: the player's clean end starts the shutdown clock; a
  // restartable service killed by a signal (kill -9, a crash, the OOM killer)
  // is restarted while it has restarts left; any other end stops the run. A
  // service that exits with a status stopped on an error it named (bad
  // config, a refused session, a device gone for good): a restart would meet
  // the same error.
  void onEnded(ChildProcess& c, int status) {
    if (isFrameSourceService(c.name()) && status == 0 && !source_done_) {
      source_done_ = Clock::now();
      spdlog::info("rekon-{} has finished; waiting for the services to finish", c.name());
    }
    if (status == 0 || stopping_ || g_interrupted.load()) return;
    const std::string error = lastErrorLine(c.logPath());
    if (c.name() == kViewer) {  // a page nobody can open is no reason to stop a run
      spdlog::warn("rekon-viewer {}{}; the run goes on without it (see {})", describeExit(status),
                   error.empty() ? "" : " (" + error + ")", c.logPath());
      return;
    }
    const std::string how = "rekon-" + c.name() + " " + describeExit(status) + (error.empty() ? "" : " (" + error + ")");
    const bool restartable = plan_.restartable.count(c.name()) > 0 && killedBySignal(status);
    if (restartable && c.restarts() < plan_.max_restarts) {
      spdlog::warn("{}; restarting it ({} of at most {} restarts, run.max_restarts)", how, c.restarts() + 1,
                   plan_.max_restarts);
      const std::vector<std::string> extra = {"--set", restartSettings().at(c.name())};
      try {
        c.restart(extra);
        spdlog::info("restarted rekon-{} (pid {})", c.name(), c.pid());
        return;
      } catch (const Error& e) {
        spdlog::error("{}", e.what());
      }
    }
    fail(how + (restartable ? " (restarted " + std::to_string(c.restarts()) + " times already)" : "") +
         "; the run was stopped, outputs so far are in " + plan_.out + "; see " + c.logPath());
  }

  // The viewer's URL (it chooses the port when viewer.port is 0), once, from its log.
  void printViewerUrl() {
    if (viewer_url_printed_) return;
    for (const auto& c : plan_.children) {
      if (c.name() != kViewer) continue;
      std::ifstream in(c.logPath());
      std::string line;
      while (std::getline(in, line)) {
        const auto at = line.find("viewer: http");
        if (at == std::string::npos) continue;
        spdlog::info("{}", line.substr(at));
        viewer_url_ = line.substr(at + 8);
        viewer_url_printed_ = true;
        return;
      }
    }
  }

  // Once a second: every running child's RSS into rss.csv.
  void sampleRss() {
    if (Clock::now() < next_rss_) return;
    next_rss_ += std::chrono::seconds(1);
    const double t = std::chrono::duration<double>(Clock::now() - start_).count();
    for (const auto& c : plan_.children) {
      if (const auto mb = c.rssMb()) rss_ << fmt::format("{:.1f},{},{:.1f}\n", t, c.name(), *mb);
    }
    rss_.flush();
  }

  // SIGTERM to the most upstream child still running (SIGKILL after kStopGraceS).
  void stopNext() {
    for (size_t i : stop_order_) {
      ChildProcess& c = plan_.children[i];
      if (!c.running()) continue;
      if (!terminated_at_[i]) {
        c.terminate();
        terminated_at_[i] = Clock::now();
      } else if (!killed_[i] && Clock::now() > *terminated_at_[i] + std::chrono::seconds(kStopGraceS)) {
        spdlog::error("rekon-{} did not stop within {} s of SIGTERM; killing it", c.name(), kStopGraceS);
        c.kill();
        killed_[i] = true;
      }
      return;  // the next one once this one has exited
    }
  }

  RunPlan& plan_;
  const double shutdown_timeout_;
  const Clock::time_point start_ = Clock::now();
  std::vector<size_t> stop_order_;
  std::vector<std::optional<Clock::time_point>> terminated_at_;
  std::vector<bool> killed_;
  std::optional<Clock::time_point> source_done_;
  bool stopping_ = false;
  bool viewer_url_printed_ = false;
  std::string viewer_url_;
  std::string failure_;
  std::ofstream rss_;
  Clock::time_point next_rss_ = Clock::now();
};

// stats.json: run-level figures (frames, wall time, restarts, realtime
// factor) plus each service's own stats file; returns the realtime factor
// (0 where there is none: a camera, an unknown recorded rate).
double writeRunStats(const RunPlan& plan, double wall, bool interrupted) {
  JsonObject stats;
  double sequence_seconds = 0;
  long long frames = 0;
  std::optional<std::pair<long long, long long>> localised_lost;  // --localise-only: the tracker's frames placed, lost
  std::vector<std::pair<std::string, std::string>> per_service;
  for (const auto& c : plan.children) {
    const std::string path = plan.out + "/" + c.name() + "_stats.json";
    if (!fs::exists(path)) continue;
    try {
      const YAML::Node node = YAML::LoadFile(path);
      if (isFrameSourceService(c.name())) {
        frames = node["frames"].as<long long>(0);
        sequence_seconds = node["sequence_seconds"].as<double>(0.0);
      }
      if (c.name() == "tracker" && plan.config.getBool("session.localise_only"))
        localised_lost.emplace(node["localised_frames"].as<long long>(0), node["lost_frames"].as<long long>(0));
      per_service.emplace_back(c.name(), jsonOf(node));
    } catch (const YAML::Exception& e) {
      spdlog::warn("{}: unreadable stats ({}); left out of stats.json", path, e.msg);
    }
  }
  stats.set("frames", frames).set("wall_seconds", wall);
  if (localised_lost) {
    stats.set("localised_frames", localised_lost->first).set("lost_frames", localised_lost->second);
    if (localised_lost->first == 0)
      spdlog::warn("no frame was placed in the session's map ({} lost): is the camera in the space that session scanned?",
                   localised_lost->second);
  }
  if (interrupted) stats.set("interrupted", true);  // Ctrl-C: the outputs cover the frames up to then
  JsonObject restarts;
  for (const auto& c : plan.children) {
    if (c.restarts() > 0) restarts.set(c.name(), static_cast<long long>(c.restarts()));
  }
  stats.setRaw("restarts", restarts.str(0));
  // A camera runs at its own rate: a realtime factor says nothing there (only
  // a dataset has a recorded rate: plan.source_fps).
  double realtime_factor = 0.0;
  if (sequence_seconds > 0 && wall > 0 && plan.source_fps > 0) {
    realtime_factor = sequence_seconds / wall;
    stats.set("realtime_factor", realtime_factor);
  }
  for (const auto& [name, json] : per_service) stats.setRaw(name, json);
  stats.save(plan.out + "/stats.json");
  return realtime_factor;
}

// The camera's one line when it lost its device mid-run ("" otherwise).
std::string cameraLost(const std::string& out) {
  for (const char* source : {"camera", "realsense"}) {
    const std::string path = out + "/" + source + "_stats.json";
    if (!fs::exists(path)) continue;
    try {
      const std::string end = YAML::LoadFile(path)["end"].as<std::string>("");
      const std::string prefix = "device lost: ";
      if (end.rfind(prefix, 0) == 0) return end.substr(prefix.size());
    } catch (const YAML::Exception&) {
    }
  }
  return "";
}

// Whether an output holds anything: a mesh with a vertex, a trajectory with a
// pose (a run that failed early writes a 243-byte mesh and a header).
bool holdsData(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  if (path.extension() == ".ply") {
    while (std::getline(in, line) && line != "end_header") {
      if (line.rfind("element vertex ", 0) == 0) return std::atoll(line.c_str() + 15) > 0;
    }
    return false;
  }
  if (path.extension() == ".txt") {
    while (std::getline(in, line)) {
      if (!line.empty() && line[0] != '#') return true;
    }
    return false;
  }
  return true;
}

// The outputs this run wrote (a file older than the run is not one of them),
// and those it wrote empty said as such.
void logOutputs(const std::string& out, fs::file_time_type started) {
  spdlog::info("outputs in {}:", out);
  std::vector<std::string> empty;
  for (const char* f : {"trajectory.txt", "mesh.ply", "mesh_uncorrected.ply", "stats.json", "report.html", "config.yaml"}) {
    const fs::path path = fs::path(out) / f;
    std::error_code ec;
    if (!fs::exists(path) || fs::last_write_time(path, ec) < started || ec) continue;
    if (holdsData(path)) spdlog::info("  {}", path.string());
    else empty.push_back(f);
  }
  spdlog::info("  logs: {}/<service>.log", out);
  if (!empty.empty()) spdlog::warn("written empty (nothing was tracked or fused): {}", fmt::join(empty, ", "));
}

}  // namespace

int launch(const RunOptions& opt) {
  const fs::file_time_type started = fs::file_time_type::clock::now();
  RunPlan plan = planRun(opt);
  signal(SIGINT, onInterrupt);
  signal(SIGTERM, onInterrupt);
  const auto start = Clock::now();
  Supervisor supervisor(plan);
  RunProgress progress(plan.config, plan.total_frames, opt.camera.empty() ? plan.config.getInt("player.first_frame") : 0,
                       plan.source_fps, start);
  supervisor.startAll();
  while (supervisor.step()) {
    progress.poll(supervisor.pids());
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  const double wall = std::chrono::duration<double>(Clock::now() - start).count();
  const bool interrupted = g_interrupted.load();
  if (removeFrameRing(plan.frame_ring)) spdlog::info("removed the frame ring '{}' left by a stopped player", plan.frame_ring);
  // With its spill files: a restartable mapper leaves it, and one that died for good too.
  if (store::KeyframeStore::remove(plan.keyframe_store)) spdlog::debug("removed the keyframe store '{}'", plan.keyframe_store);

  progress.finish(writeRunStats(plan, wall, interrupted), interrupted);
  if (opt.report) {
    try {
      report::writeRunReport(plan.out);
    } catch (const Error& e) {
      spdlog::error("report: {}", e.what());  // the run's own outputs stay as they are
    }
  }
  logOutputs(plan.out, started);
  supervisor.serveFinalMap(plan.config.getDouble("viewer.serve_after_run_s"));
  if (!supervisor.failure().empty()) {
    spdlog::error("{}", supervisor.failure());  // again as the last line
    return 1;
  }
  if (const std::string lost = cameraLost(plan.out); !lost.empty()) {
    spdlog::error("the run ended early: {}", lost);  // outputs up to then are written
    return 1;
  }
  return interrupted ? 130 : 0;  // Ctrl-C while the viewer served a finished run is its normal end
}

int runCommand(int argc, char** argv) {
  ArgParser args("rekon run", "Runs the whole pipeline (every service as its own process) on a dataset or a live camera.");
  args.option("dataset", "TUM RGB-D folder with camera.yaml (this or --camera)")
      .option("camera", "a live camera instead of a dataset: realsense[:SERIAL] (Intel's SDK; rekon-realsense --list), "
                        "openni2[:URI|FILE.oni] or freenect[:INDEX] (rekon cameras)")
      .option("playback", "with --camera realsense: play this .bag recording at its recorded rate instead of a camera")
      .option("calibration", "with --camera: camera.yaml for the device (default: what the device reports)")
      .option("record", "with --camera: also record every captured frame into this new folder (a TUM dataset)")
      .option("out", "output folder (required)")
      .option("session", "also keep a session in this new folder as the run goes: rekon remesh and rekon export read it")
      .option("continue", "extend the session in this folder: relocalise against it, then map into it (same camera)")
      .flag("localise-only", "with --continue: only localise in that session's map (tracker alone; poses on the bus and "
                             "in trajectory.txt); the session stays as it is")
      .option("config", "YAML config laid over config/default.yaml")
      .repeated("set", "override one config key, e.g. --set volume.voxel_size=0.02")
      .flag("report", "also write report.html (mesh views, trajectory, timing, stats) into --out")
      .flag("view", "also start rekon-viewer, a live web page of the run (its URL is printed); after the run it keeps "
                    "showing the final map until Ctrl-C (viewer.serve_after_run_s)")
      .flag("force", "--out may hold an earlier run: replace its files (without it such a folder is refused)")
      .examples("rekon run --dataset ../shared/data/7scenes_loop_1000 --out out/7scenes --report\n"
                "rekon run --dataset out/room --out out/room_run --view --set mapper.kappa=10\n"
                "rekon run --camera openni2 --out out/live --record out/live_frames --session out/live_session\n"
                "rekon run --camera realsense --out out/rs --set realsense.preset=high_accuracy\n"
                "rekon run --camera realsense --playback scan.bag --out out/scan\n"
                "rekon run --dataset DATA --out OUT --continue out/live_session   # extend a session\n"
                "rekon run --dataset DATA --out OUT --continue out/live_session --localise-only   # localise in it");
  if (!args.parse(argc, argv)) return 0;
  RunOptions opt;
  opt.dataset = args.get("dataset");
  opt.camera = args.get("camera");
  opt.calibration = args.get("calibration");
  opt.record = args.get("record");
  opt.playback = args.get("playback");
  opt.out = args.get("out");
  opt.session = args.get("session");
  opt.continued = args.get("continue");
  opt.localise_only = args.flagSet("localise-only");
  opt.config_file = args.get("config");
  opt.sets = args.all("set");
  opt.report = args.flagSet("report");
  opt.view = args.flagSet("view");
  opt.force = args.flagSet("force");
  if (!opt.dataset.empty() && !opt.camera.empty()) {
    throw Error("--dataset plays a recorded sequence and --camera runs a live camera; give one of them");
  }
  if (opt.dataset.empty() == opt.camera.empty() || opt.out.empty()) {
    throw Error("rekon run needs --out and one of --dataset DIR or --camera DEVICE; see rekon run --help");
  }
  if (!opt.session.empty() && !opt.continued.empty())
    throw Error("--session starts a new session and --continue extends one; give one of them");
  if (opt.localise_only && opt.continued.empty())
    throw Error("--localise-only localises in a saved session: give the session with --continue SESSION");
  if (!opt.playback.empty() && !isRealSense(opt.camera)) {
    throw Error("--playback plays a RealSense .bag recording: give it with --camera realsense (an OpenNI2 recording "
                "is --camera openni2:FILE.oni)");
  }
  if (opt.camera.empty() && !(opt.calibration.empty() && opt.record.empty())) {
    throw Error("--calibration and --record go with --camera (a dataset has its own camera.yaml)");
  }
  return launch(opt);
}

int demoCommand(int argc, char** argv) {
  ArgParser args("rekon demo", "Runs the whole pipeline on the built-in default scene (synthetic room) and prints where "
                               "the outputs are; a demo run in --out replaces the earlier one.");
  const fs::path root = fs::path(executableDir()).parent_path().parent_path();
  args.option("out", "output folder", (root / "out" / "demo").string())
      .option("frames", "frames of the synthetic room (0 = its default, 600)", "0")
      .repeated("set", "override one config key, e.g. --set mapper.kappa=10")
      .flag("view", "also show the run in a live web page (its URL is printed; it stays until Ctrl-C)")
      .examples("rekon demo\nrekon demo --frames 300 --view\nrekon demo --out out/demo_k10 --set mapper.kappa=10");
  if (!args.parse(argc, argv)) return 0;
  const fs::path out(args.get("out"));
  synth::SequenceOptions scene;
  scene.scene = "room";
  scene.frames = args.getInt("frames");
  const fs::path data = out / ("room_" + std::to_string(scene.frames) + "_data");
  if (!fs::exists(data / "groundtruth.txt")) {
    setupLogging("demo", "info");
    spdlog::info("demo: generating the synthetic room into {} (once)", data.string());
    synth::writeSequenceShowingProgress(scene, data.string());
  }
  RunOptions opt;
  opt.dataset = data.string();
  opt.out = out.string();
  opt.sets = args.all("set");
  opt.report = true;
  opt.view = args.flagSet("view");
  opt.force = true;  // the demo's folder: a second demo replaces the first
  const int rc = launch(opt);
  if (rc == 0 && fs::exists(out / "trajectory.txt")) {
    spdlog::info("compare with the ground truth: tools/rekon eval traj {} {}", (data / "groundtruth.txt").string(),
                 (out / "trajectory.txt").string());
  }
  if (rc == 0 && fs::exists(out / "report.html")) {
    spdlog::info("the report, with the surface against the ground truth (CORR, COMPL): {}", (out / "report.html").string());
  }
  return rc;
}

}  // namespace rekon
