// rekon bench keyframes: the paper's Figure 5. Every frame is fused at its
// ground-truth pose, so only keyframe fusion differs between the runs; each
// strategy and parameter gives one point (average keyframe size kappa-bar,
// CORR, COMPL) against the reference: every raw frame integrated at its
// ground-truth pose (kappa = 1, no fusion), as the paper's section 5.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <optional>

#include "bench_data.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/json.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/eval/surface_eval.hpp"
#include "rekon/mapper/mapper.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"
#include "rekon/mapper_bench/bench_command.hpp"
#include "rekon/report/plot.hpp"

namespace rekon::mapper_bench {
namespace fs = std::filesystem;
namespace {

struct StrategyRun {
  fusion::KeyframeStrategy strategy;
  std::string parameter;  // what was swept, e.g. "kappa=20" or "t=0.1;r=10"
  fusion::FusionParams fusion;
};

struct StrategyResult {
  StrategyRun run;
  int64_t frames = 0, keyframes = 0;
  double kappa_bar = 0.0;
  eval::SurfaceErrors errors;
  double fuse_ms_per_frame = 0.0, integrate_ms_per_frame = 0.0;
};

Mesh referenceMesh(const BenchFrames& data, const volume::VolumeParams& params) {
  volume::TsdfVolume v(params);
  for (size_t i = 0; i < data.frames.size(); ++i) {
    v.streamAround(data.poses[i].translation());
    v.integrate(volume::depthToMetres(data.frames[i].depth, data.k.depth_scale), data.frames[i].color, cv::Mat(),
                data.k, data.poses[i]);
  }
  return v.extractMesh();
}

// Feeds every frame at its pose; DVO keyframes are the tracker's when given,
// else each frame anchors itself (only KF_DVO needs the tracker's).
StrategyResult fuseAndEvaluate(const BenchFrames& data, const std::optional<TrackingRun>& dvo, mapper::MapperParams params,
                               const StrategyRun& run, const Mesh& reference) {
  params.fusion = run.fusion;
  params.mode = mapper::ReintegrationMode::kNone;
  params.use_store = false;
  mapper::Mapper m(params);
  std::map<int64_t, Pose> anchors;
  for (size_t i = 0; i < data.frames.size(); ++i) {
    const int64_t anchor = dvo ? dvo->keyframe_of_frame[i] : static_cast<int64_t>(i);
    auto it = anchors.find(anchor);
    if (it == anchors.end()) {
      it = anchors.emplace(anchor, data.poses[i]).first;
      m.setKeyframeEstimate(anchor, data.poses[i]);
    }
    m.addFrame(data.frames[i], data.k, anchor, it->second.inverse() * data.poses[i], false);
  }
  m.finish();
  StrategyResult r;
  r.run = run;
  r.frames = m.counters().frames;
  r.keyframes = m.counters().kf_keyframes;
  r.kappa_bar = static_cast<double>(r.frames) / static_cast<double>(std::max<int64_t>(1, r.keyframes));
  r.fuse_ms_per_frame = m.counters().fuse_ms_total / static_cast<double>(std::max<int64_t>(1, r.frames));
  r.integrate_ms_per_frame = m.counters().first_integration_ms_total / static_cast<double>(std::max<int64_t>(1, r.frames));
  r.errors = eval::evaluateSurface(m.extractMesh(), reference);
  return r;
}

void writeCsv(const std::vector<StrategyResult>& results, const std::string& path) {
  std::ofstream out(path);
  out << "strategy,parameter,frames,kf_keyframes,kappa_bar,corr_mm,compl_mm,fuse_ms_per_frame,integrate_ms_per_frame\n";
  for (const StrategyResult& r : results) {
    char line[256];
    std::snprintf(line, sizeof line, "%s,%s,%lld,%lld,%.4f,%.4f,%.4f,%.3f,%.3f", fusion::toString(r.run.strategy).c_str(),
                  r.run.parameter.c_str(), static_cast<long long>(r.frames), static_cast<long long>(r.keyframes),
                  r.kappa_bar, 1e3 * r.errors.corr_m, 1e3 * r.errors.compl_m, r.fuse_ms_per_frame,
                  r.integrate_ms_per_frame);
    out << line << "\n";
  }
  if (!out) throw Error(path + ": cannot write; check that --out is writable");
}

void writePlots(const std::vector<StrategyResult>& results, const std::string& out_dir, const std::string& dataset) {
  for (const bool corr : {true, false}) {
    report::PlotOptions o;
    o.title = std::string(corr ? "CORR" : "COMPL") + " against keyframe size (" + dataset + ")";
    o.x_label = "average keyframe size kappa-bar [frames]";
    o.y_label = std::string(corr ? "CORR" : "COMPL") + " [mm]";
    o.x_scale = o.y_scale = report::Scale::Log;
    report::LinePlot plot(o);
    for (const auto s : {fusion::KeyframeStrategy::kConst, fusion::KeyframeStrategy::kDvo, fusion::KeyframeStrategy::kDist,
                         fusion::KeyframeStrategy::kOverlap}) {
      std::vector<std::pair<double, double>> points;
      for (const StrategyResult& r : results) {
        if (r.run.strategy == s) points.emplace_back(r.kappa_bar, 1e3 * (corr ? r.errors.corr_m : r.errors.compl_m));
      }
      if (points.empty()) continue;
      std::sort(points.begin(), points.end());
      report::Series series;
      series.name = "KF_" + fusion::toString(s);
      for (const auto& [x, y] : points) {
        series.x.push_back(x);
        series.y.push_back(y);
      }
      series.markers = true;
      series.line = s == fusion::KeyframeStrategy::kConst;  // one parameter: a curve; the others are scattered points
      plot.add(std::move(series));
    }
    plot.save((fs::path(out_dir) / (corr ? "keyframes_corr.svg" : "keyframes_compl.svg")).string());
  }
}

std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

// The runs --kappas, --no-dvo, --dist and --overlaps ask for, each from `base`.
std::vector<StrategyRun> strategyRuns(const ArgParser& args, const fusion::FusionParams& base) {
  std::vector<StrategyRun> runs;
  for (double kappa : parseNumberList(args.get("kappas"), "kappas")) {
    if (kappa < 1 || kappa != static_cast<int>(kappa)) throw Error("--kappas: " + number(kappa) + " is not a whole number >= 1");
    StrategyRun r{fusion::KeyframeStrategy::kConst, "kappa=" + number(kappa), base};
    r.fusion.strategy = r.strategy;
    r.fusion.kappa = static_cast<int>(kappa);
    runs.push_back(r);
  }
  if (!args.flagSet("no-dvo")) {
    StrategyRun r{fusion::KeyframeStrategy::kDvo, "tracker", base};
    r.fusion.strategy = r.strategy;
    runs.push_back(r);
  }
  for (const auto& [t, deg] : parsePairList(args.get("dist"), "dist")) {
    StrategyRun r{fusion::KeyframeStrategy::kDist, "t=" + number(t) + ";r=" + number(deg), base};
    r.fusion.strategy = r.strategy;
    r.fusion.dist_translation = t;
    r.fusion.dist_rotation_deg = deg;
    runs.push_back(r);
  }
  for (double o : parseNumberList(args.get("overlaps"), "overlaps")) {
    StrategyRun r{fusion::KeyframeStrategy::kOverlap, "min_overlap=" + number(o), base};
    r.fusion.strategy = r.strategy;
    r.fusion.min_overlap = o;
    runs.push_back(r);
  }
  return runs;
}

}  // namespace

int benchKeyframesCommand(int argc, char** argv) {
  ArgParser args(argv[0],
                 "The paper's Figure 5: for each KF keyframe strategy and parameter, the average keyframe size "
                 "kappa-bar and CORR / COMPL (mm) of the fused surface against the reference (every raw frame "
                 "integrated at its ground-truth pose). Frames are fused at their ground-truth poses; KF_DVO takes "
                 "its keyframes from the DVO tracker run over the same frames. Writes keyframes.csv, "
                 "keyframes_corr.svg, keyframes_compl.svg (each with its .csv) and reference.ply into --out. The "
                 "last line printed is const_kappa1_compl_mm=... const_kappa20_compl_mm=... compl_20_over_1=...");
  args.option("dataset", "TUM-layout dataset with groundtruth.txt")
      .option("out", "output folder")
      .option("frames", "use at most this many frames (0 = all)", "0")
      .option("step", "use every step-th frame", "1")
      .option("kappas", "KF_CONST: frames per keyframe", "1,2,5,10,20,50,100")
      .option("dist", "KF_DIST: translation_m:rotation_deg thresholds", "0.05:5,0.1:10,0.2:20,0.4:40")
      .option("overlaps", "KF_OVRLP: minimum overlap ratios", "0.9,0.8,0.7,0.5")
      .flag("no-dvo", "leave out KF_DVO (and the tracker run it needs)")
      .flag("wall", "time in wall clock instead of the process's CPU time")
      .option("config", "YAML file laid over config/default.yaml (volume and mapper settings)")
      .repeated("set", "override one key, e.g. --set volume.voxel_size=0.02");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("dataset") || !args.has("out")) throw Error("--dataset and --out are required; see rekon bench keyframes --help");
  const Config config = Config::load(args.has("config") ? args.get("config") : "", args.all("set"));
  setupLogging("bench", config.getString("log.level"));
  const std::string out_dir = args.get("out");
  createOutputFolder(out_dir);

  mapper::MapperParams base = mapper::MapperParams::fromConfig(config);
  base.cpu_time_counters = !args.flagSet("wall");
  // The paper's Figure 5 measures each strategy as defined, uncapped: the
  // sequences are finite and the sweep's own frames bound the memory.
  base.fusion.max_frames_per_keyframe = std::numeric_limits<int>::max();
  const std::vector<StrategyRun> runs = strategyRuns(args, base.fusion);
  for (const StrategyRun& r : runs) r.fusion.validate();  // before minutes of loading

  const auto start = std::chrono::steady_clock::now();
  const BenchFrames data = loadFrames(args.get("dataset"), (fs::path(args.get("dataset")) / "groundtruth.txt").string(),
                                      args.getInt("frames"), args.getInt("step"));
  std::optional<TrackingRun> dvo;
  if (!args.flagSet("no-dvo")) dvo = runTracker(data, config, !args.flagSet("wall"));
  const Mesh reference = referenceMesh(data, base.volume);
  writePly(reference, (fs::path(out_dir) / "reference.ply").string());
  spdlog::info("bench: reference of {} raw frames at ground truth: {} vertices", data.frames.size(), reference.vertices.size());

  std::vector<StrategyResult> results;
  for (const StrategyRun& run : runs) {
    results.push_back(fuseAndEvaluate(data, dvo, base, run, reference));
    const StrategyResult& r = results.back();
    std::printf("KF_%-8s %-16s keyframes %5lld kappa-bar %7.2f  CORR %6.2f mm  COMPL %6.2f mm\n",
                fusion::toString(r.run.strategy).c_str(), r.run.parameter.c_str(), static_cast<long long>(r.keyframes),
                r.kappa_bar, 1e3 * r.errors.corr_m, 1e3 * r.errors.compl_m);
    std::fflush(stdout);
  }
  writeCsv(results, (fs::path(out_dir) / "keyframes.csv").string());
  writePlots(results, out_dir, fs::path(args.get("dataset")).filename().string());
  spdlog::info("bench: {} runs on {} frames in {:.0f} s; {}/keyframes.csv", results.size(), data.frames.size(),
               std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), out_dir);

  auto constCompl = [&](int kappa) -> double {
    for (const StrategyResult& r : results)
      if (r.run.strategy == fusion::KeyframeStrategy::kConst && r.run.fusion.kappa == kappa) return 1e3 * r.errors.compl_m;
    return NAN;
  };
  const double c1 = constCompl(1), c20 = constCompl(20);
  std::cout << keyValueLine({{"const_kappa1_compl_mm", c1}, {"const_kappa20_compl_mm", c20}, {"compl_20_over_1", c20 / c1}})
            << std::endl;
  return 0;
}

}  // namespace rekon::mapper_bench
