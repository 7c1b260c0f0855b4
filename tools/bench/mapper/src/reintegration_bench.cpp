// rekon bench reintegration: the paper's Figure 7. The mapper
// (services/mapper, the same code rekon-mapper runs) is fed the
// frames at the poses of a drifted trajectory, and graph updates move the
// DVO keyframes toward the ground truth exactly as rekon-replay does
// (services/replay's ReplayScript). For every kappa, m = m_total / kappa
// keyframes are re-integrated per update, once choosing the m consecutive
// keyframes of eq. (3) and once the m most-moved (BundleFusion).
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>

#include "bench_data.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/json.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/mapper/mapper.hpp"
#include "rekon/mapper_bench/bench_command.hpp"
#include "rekon/replay/replay.hpp"
#include "rekon/report/plot.hpp"
#include "rekon/report/run_files.hpp"

namespace rekon::mapper_bench {
namespace fs = std::filesystem;
namespace {

// The paper's two operating points.
constexpr int kOursKappa = 20;
constexpr int kBundleFusionKappa = 1;

struct RunResult {
  int kappa = 0, m = 0;
  mapper::ReintegrationMode mode = mapper::ReintegrationMode::kConsecutive;
  int64_t frames = 0, keyframes = 0, graph_updates = 0, reintegrated = 0, final_pass_keyframes = 0;
  double integration_ms = 0, reintegration_ms = 0, fuse_ms = 0, final_pass_ms = 0;
  int64_t blocks_streamed_in_rounds = 0, streamed_out = 0, streamed_in = 0;

  double perFrame(double ms) const { return ms / static_cast<double>(std::max<int64_t>(1, frames)); }
  // The red lines of Figure 7: first integrations and the graph-update rounds, amortised over the frames.
  double reintegrationPerFrame() const { return perFrame(integration_ms + reintegration_ms); }
};

RunResult playReplay(const BenchFrames& data, const Trajectory& source, const Trajectory& target,
                     const replay::ReplayParams& rp, mapper::MapperParams params, int kappa, int m,
                     mapper::ReintegrationMode mode) {
  params.fusion.strategy = fusion::KeyframeStrategy::kConst;
  params.fusion.kappa = kappa;
  params.m = m;
  params.mode = mode;
  params.use_store = false;
  mapper::Mapper mapper(params);
  replay::ReplayScript script(source, target, rp, static_cast<int64_t>(data.frames.size()));
  for (const RgbdFrame& f : data.frames) {
    const replay::ReplayTracked t = script.onFrame(f.id, f.timestamp);
    if (t.new_keyframe_world) mapper.setKeyframeEstimate(t.keyframe_id, *t.new_keyframe_world);
    mapper.addFrame(f, data.k, t.keyframe_id, t.pose_in_keyframe, t.lost);
    if (auto u = script.dueUpdate()) mapper.applyGraphUpdate(u->poses);
  }
  for (const replay::ReplayGraphUpdate& u : script.finalUpdates()) mapper.applyGraphUpdate(u.poses);
  mapper.finish();
  const mapper::MapperCounters& c = mapper.counters();
  const volume::VolumeStats vs = mapper.volume().stats();
  RunResult r;
  r.kappa = kappa;
  r.m = m;
  r.mode = mode;
  r.frames = c.frames;
  r.keyframes = c.kf_keyframes;
  r.graph_updates = c.graph_updates;
  r.reintegrated = c.reintegrations - c.final_pass_reintegrations;
  r.final_pass_keyframes = c.final_pass_reintegrations;
  r.integration_ms = c.first_integration_ms_total;
  r.reintegration_ms = c.reintegration_ms_total;
  r.fuse_ms = c.fuse_ms_total;
  r.final_pass_ms = c.final_pass_ms_total;
  r.blocks_streamed_in_rounds = c.reintegration_blocks_streamed;
  r.streamed_out = vs.streamed_out;
  r.streamed_in = vs.streamed_in;
  return r;
}

double meanTrackingMs(const std::string& csv) {
  const report::CsvTable t = report::readCsvTable(csv, report::kTimingColumns);
  double sum = 0;
  int n = 0;
  for (double v : t.values(1)) {
    if (std::isfinite(v)) sum += v, ++n;
  }
  if (n == 0) throw Error(csv + ": no finite ms values; give the tracker_timing.csv of a run");
  return sum / n;
}

void writeCsv(const std::vector<RunResult>& runs, double tracking_ms, const std::string& path) {
  std::ofstream out(path);
  out << "kappa,m,mode,frames,kf_keyframes,graph_updates,keyframes_reintegrated,integration_ms_per_frame,"
         "reintegration_ms_per_frame,reintegration_total_ms_per_frame,fuse_ms_per_frame,tracking_ms_per_frame,"
         "total_ms_per_frame,final_pass_keyframes,final_pass_ms,blocks_streamed_in_rounds,streamed_out,streamed_in\n";
  for (const RunResult& r : runs) {
    char line[512];
    std::snprintf(line, sizeof line, "%d,%d,%s,%lld,%lld,%lld,%lld,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%lld,%.1f,%lld,%lld,%lld",
                  r.kappa, r.m, mapper::toString(r.mode).c_str(), static_cast<long long>(r.frames),
                  static_cast<long long>(r.keyframes), static_cast<long long>(r.graph_updates),
                  static_cast<long long>(r.reintegrated), r.perFrame(r.integration_ms), r.perFrame(r.reintegration_ms),
                  r.reintegrationPerFrame(), r.perFrame(r.fuse_ms), tracking_ms,
                  tracking_ms + r.perFrame(r.fuse_ms) + r.reintegrationPerFrame(),
                  static_cast<long long>(r.final_pass_keyframes), r.final_pass_ms,
                  static_cast<long long>(r.blocks_streamed_in_rounds), static_cast<long long>(r.streamed_out),
                  static_cast<long long>(r.streamed_in));
    out << line << "\n";
  }
  if (!out) throw Error(path + ": cannot write; check that --out is writable");
}

void writePlot(const std::vector<RunResult>& runs, double tracking_ms, const std::string& path, int m_total,
               bool cpu_time) {
  report::PlotOptions o;
  o.title = "average runtime per frame, KF_CONST, m = " + std::to_string(m_total) + " / kappa";
  o.x_label = "kappa [frames per KF keyframe]";
  o.y_label = cpu_time ? "ms CPU time per frame" : "ms wall time per frame";
  o.x_scale = o.y_scale = report::Scale::Log;
  report::LinePlot plot(o);
  // Figure 7's colours: red (re-)integration, green tracking, blue total; dashed = BundleFusion's selection.
  for (const auto mode : {mapper::ReintegrationMode::kConsecutive, mapper::ReintegrationMode::kMostMoved}) {
    report::Series reint, total;
    reint.name = "(re-)integration, " + mapper::toString(mode);
    total.name = "total, " + mapper::toString(mode);
    for (const RunResult& r : runs) {
      if (r.mode != mode) continue;
      reint.x.push_back(r.kappa);
      reint.y.push_back(r.reintegrationPerFrame());
      total.x.push_back(r.kappa);
      total.y.push_back(tracking_ms + r.perFrame(r.fuse_ms) + r.reintegrationPerFrame());
    }
    reint.color = "#D55E00";
    total.color = "#0072B2";
    reint.markers = total.markers = true;
    reint.dashed = total.dashed = mode == mapper::ReintegrationMode::kMostMoved;
    plot.add(std::move(reint)).add(std::move(total));
  }
  report::Series track;
  track.name = "DVO tracking";
  track.color = "#009E73";
  for (const RunResult& r : runs) {
    if (r.mode != mapper::ReintegrationMode::kConsecutive) continue;
    track.x.push_back(r.kappa);
    track.y.push_back(tracking_ms);
  }
  plot.add(std::move(track));
  plot.save(path);
}

const RunResult& find(const std::vector<RunResult>& runs, int kappa, mapper::ReintegrationMode mode) {
  for (const RunResult& r : runs)
    if (r.kappa == kappa && r.mode == mode) return r;
  throw Error("internal: no run for kappa " + std::to_string(kappa));
}

// --kappas, whole numbers >= 1, with the two the headline compares, sorted and unique.
std::vector<int> kappaList(const std::string& text) {
  std::vector<int> kappas;
  for (double k : parseNumberList(text, "kappas")) {
    if (k < 1 || k != static_cast<int>(k)) throw Error("--kappas: every entry must be a whole number >= 1");
    kappas.push_back(static_cast<int>(k));
  }
  kappas.push_back(kBundleFusionKappa);
  kappas.push_back(kOursKappa);
  std::sort(kappas.begin(), kappas.end());
  kappas.erase(std::unique(kappas.begin(), kappas.end()), kappas.end());
  return kappas;
}

// The headline: kappa 20, m 5, consecutive against kappa 1, m 100, most_moved
// (BundleFusion's setting) and against most_moved at kappa 20.
void printHeadline(const std::vector<RunResult>& runs, double tracking_ms, const std::string& tracking_source,
                   bool cpu_time) {
  const RunResult& ours = find(runs, kOursKappa, mapper::ReintegrationMode::kConsecutive);
  const RunResult& ours_mm = find(runs, kOursKappa, mapper::ReintegrationMode::kMostMoved);
  const RunResult& bf = find(runs, kBundleFusionKappa, mapper::ReintegrationMode::kMostMoved);
  const auto withFusion = [&](const RunResult& r) { return r.perFrame(r.fuse_ms) + r.reintegrationPerFrame(); };
  std::cout << "times in " << (cpu_time ? "process CPU" : "wall") << " ms; tracking " << tracking_ms << " ms/frame ("
            << tracking_source << "); kappa " << kOursKappa << " m " << ours.m << ": blocks streamed in rounds consecutive "
            << ours.blocks_streamed_in_rounds << ", most_moved " << ours_mm.blocks_streamed_in_rounds << "\n";
  std::cout << keyValueLine({{"with_fusion_ours_over_bundlefusion", withFusion(ours) / withFusion(bf)},
                             {"total_ours_over_bundlefusion", (tracking_ms + withFusion(ours)) / (tracking_ms + withFusion(bf))},
                             {"blocks_streamed_consecutive", static_cast<double>(ours.blocks_streamed_in_rounds)},
                             {"blocks_streamed_most_moved", static_cast<double>(ours_mm.blocks_streamed_in_rounds)}})
            << "\n";
  std::cout << keyValueLine({{"ours_over_bundlefusion", ours.reintegrationPerFrame() / bf.reintegrationPerFrame()},
                             {"consecutive_over_most_moved", ours.reintegrationPerFrame() / ours_mm.reintegrationPerFrame()}})
            << std::endl;
}

}  // namespace

int benchReintegrationCommand(int argc, char** argv) {
  ArgParser args(argv[0],
                 "The paper's Figure 7: average amortised (re-)integration time per frame against kappa "
                 "(KF_CONST, m = m-total / kappa keyframes per graph update) for consecutive (eq. 3) and "
                 "most_moved (BundleFusion) re-integration, with tracking time and the total. Frames are fused at "
                 "the --trajectory poses; graph updates move the DVO keyframes toward --target as rekon-replay "
                 "does. Kappa 1 and 20 are always run. Writes reintegration.csv and reintegration_plot.svg (its data in reintegration_plot.csv). "
                 "The last line is ours_over_bundlefusion=X consecutive_over_most_moved=Y: (re-)integration time "
                 "of kappa 20, m 5, consecutive over kappa 1, m 100, most_moved, and consecutive over most_moved "
                 "at kappa 20, m 5.");
  args.option("dataset", "TUM-layout dataset (e.g. rekon synth --scene corridor --drift 0.03,1.5)")
      .option("out", "output folder")
      .option("frames", "use at most this many frames (0 = all)", "0")
      .option("step", "use every step-th frame", "1")
      .option("kappas", "KF_CONST keyframe sizes", "1,2,5,10,20,50")
      .option("m-total", "m = m-total / kappa keyframes re-integrated per graph update (rounded, at least 1)", "100")
      .option("trajectory", "poses the frames are fused at (default DATASET/drifted_trajectory.txt)")
      .option("target", "poses the graph updates move the keyframes to (default DATASET/groundtruth.txt)")
      .option("update-every", "a graph update every N DVO keyframes", std::to_string(replay::ReplayParams::kDefaultUpdateEveryKeyframes))
      .flag("wall", "time in wall clock instead of the process's CPU time (the default: a shared machine inflates wall time)")
      .option("tracking-csv", "take the tracking time from this tracker_timing.csv instead of running the tracker")
      .option("config", "YAML file laid over config/default.yaml (volume, mapper, tracker settings)")
      .repeated("set", "override one key, e.g. --set mapper.streaming_radius=2");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("dataset") || !args.has("out")) throw Error("--dataset and --out are required; see rekon bench reintegration --help");
  const Config config = Config::load(args.has("config") ? args.get("config") : "", args.all("set"));
  setupLogging("bench", config.getString("log.level"));
  const std::string out_dir = args.get("out");
  createOutputFolder(out_dir);
  const fs::path dataset(args.get("dataset"));
  const std::string source_file = args.has("trajectory") ? args.get("trajectory") : (dataset / "drifted_trajectory.txt").string();
  const std::string target_file = args.has("target") ? args.get("target") : (dataset / "groundtruth.txt").string();
  if (!fs::exists(source_file))
    throw Error(source_file + ": not found; give --trajectory, or a dataset written by rekon synth --drift T,R");
  const int m_total = args.getInt("m-total");
  if (m_total < 1) throw Error("--m-total must be at least 1");
  const std::vector<int> kappas = kappaList(args.get("kappas"));

  replay::ReplayParams rp;
  rp.trajectory = source_file;
  rp.target = target_file;
  rp.update_every_keyframes = args.getInt("update-every");
  rp.validate();
  mapper::MapperParams base = mapper::MapperParams::fromConfig(config);
  base.cpu_time_counters = !args.flagSet("wall");
  // The paper's memory model (Figure 7's streaming): only the sphere stays
  // active, whatever mapper.active_mb says; the host tier as configured. And
  // its rounds: each graph update's keyframes corrected at once, whatever
  // mapper.round_budget_ms says.
  base.volume.active_max_blocks = 0;
  base.round_budget_ms = 0.0;
  const BenchFrames data = loadFrames(dataset.string(), target_file, args.getInt("frames"), args.getInt("step"));
  const Trajectory source = readTumTrajectory(source_file), target = readTumTrajectory(target_file);
  const double tracking_ms =
      args.has("tracking-csv") ? meanTrackingMs(args.get("tracking-csv")) : runTracker(data, config, base.cpu_time_counters).ms_per_frame;

  std::vector<RunResult> runs;
  for (int kappa : kappas) {
    const int m = std::max(1, static_cast<int>(std::lround(static_cast<double>(m_total) / kappa)));
    for (const auto mode : {mapper::ReintegrationMode::kConsecutive, mapper::ReintegrationMode::kMostMoved}) {
      runs.push_back(playReplay(data, source, target, rp, base, kappa, m, mode));
      const RunResult& r = runs.back();
      std::printf("kappa %3d m %3d %-11s keyframes %5lld updates %4lld re-integrated %6lld  (re-)integration %8.2f ms/frame"
                  "  fusion %6.2f ms/frame  blocks streamed in rounds %8lld  final pass %lld keyframes %.0f ms\n",
                  kappa, m, mapper::toString(mode).c_str(), static_cast<long long>(r.keyframes),
                  static_cast<long long>(r.graph_updates), static_cast<long long>(r.reintegrated),
                  r.reintegrationPerFrame(), r.perFrame(r.fuse_ms), static_cast<long long>(r.blocks_streamed_in_rounds),
                  static_cast<long long>(r.final_pass_keyframes), r.final_pass_ms);
      std::fflush(stdout);
    }
  }
  writeCsv(runs, tracking_ms, (fs::path(out_dir) / "reintegration.csv").string());
  writePlot(runs, tracking_ms, (fs::path(out_dir) / "reintegration_plot.svg").string(), m_total,
            base.cpu_time_counters);
  printHeadline(runs, tracking_ms, args.has("tracking-csv") ? args.get("tracking-csv") : "DVO tracker on these frames",
                base.cpu_time_counters);
  return 0;
}

}  // namespace rekon::mapper_bench
