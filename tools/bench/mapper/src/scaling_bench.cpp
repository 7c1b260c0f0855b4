// `rekon bench scaling` (issue 19): does a KF keyframe's integration or a
// graph update's re-integration round get slower as the map grows? The mapper
// (services/mapper, the code rekon-mapper runs) is fed a synthetic scene
// rendered in this process (default: the corridor, 3 laps, 15 808 frames) at
// the poses of a drifted trajectory, and graph updates move the DVO keyframes
// toward the ground truth as rekon-replay does (the reintegration bench's
// driver). Every --every frames it prints the map's size and the mean ms of
// the integrations and of the rounds since the last line; the curve goes to
// scaling.csv and scaling_plot.svg (log-log against the KF keyframes in the map).
// Rendering is not timed; times are the process's CPU time unless --wall.
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "bench_data.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/json.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/common/memory.hpp"
#include "rekon/common/service.hpp"
#include "rekon/mapper/mapper.hpp"
#include "rekon/mapper_bench/bench_command.hpp"
#include "rekon/replay/replay.hpp"
#include "rekon/report/plot.hpp"
#include "rekon/synth/synth.hpp"

namespace rekon::mapper_bench {
namespace {

// One line of the curve: the map at `frames`, and the mean times since the previous line.
struct ScalingPoint {
  int64_t frames = 0, kf_keyframes = 0, blocks = 0, integrations = 0, rounds = 0;
  double integration_ms = 0.0;  // per first integration of a KF keyframe
  double round_ms = 0.0;        // per graph-update round (de-integration, re-integration, streaming)
  // Per round: blocks its (de-)integrations updated, and blocks it streamed in or out of the active pool.
  double round_blocks_updated = 0.0, round_blocks_streamed = 0.0;
  // Memory now: the process, and the voxel tiers (mapper.active_mb, mapper.host_mb, disk).
  double rss_mb = 0.0, active_mb = 0.0, host_mb = 0.0, disk_mb = 0.0;
};

// Counters of the mapper at one moment, to take differences of.
struct Totals {
  int64_t integrations = 0, rounds = 0;
  double integration_ms = 0.0, round_ms = 0.0;
  int64_t round_blocks_updated = 0, round_blocks_streamed = 0;
  static Totals of(const mapper::MapperCounters& c, int64_t round_blocks_updated) {
    return {c.integrations, c.graph_updates, c.first_integration_ms_total, c.reintegration_ms_total,
            round_blocks_updated, c.reintegration_blocks_streamed};
  }
};

ScalingPoint pointSince(const Totals& before, const mapper::Mapper& m, int64_t round_blocks_updated) {
  const mapper::MapperCounters& c = m.counters();
  const Totals now = Totals::of(c, round_blocks_updated);
  ScalingPoint p;
  p.frames = c.frames;
  p.kf_keyframes = c.kf_keyframes;
  p.blocks = m.volume().stats().blocks;
  p.integrations = now.integrations - before.integrations;
  p.rounds = now.rounds - before.rounds;
  p.integration_ms = p.integrations > 0 ? (now.integration_ms - before.integration_ms) / static_cast<double>(p.integrations) : 0.0;
  const auto per_round = [&](double total) { return p.rounds > 0 ? total / static_cast<double>(p.rounds) : 0.0; };
  p.round_ms = per_round(now.round_ms - before.round_ms);
  p.round_blocks_updated = per_round(static_cast<double>(now.round_blocks_updated - before.round_blocks_updated));
  p.round_blocks_streamed = per_round(static_cast<double>(now.round_blocks_streamed - before.round_blocks_streamed));
  const mapper::MemoryUse mem = m.memoryUse();
  p.rss_mb = currentRssMb();
  p.active_mb = static_cast<double>(mem.active_voxel_bytes) / 1048576.0;
  p.host_mb = static_cast<double>(mem.host_voxel_bytes_in_memory) / 1048576.0;
  p.disk_mb = static_cast<double>(mem.voxel_bytes_on_disk) / 1048576.0;
  return p;
}

// RSS and the voxel tiers against frames: memory_plot.svg (its data in memory_plot.csv).
void writeMemoryPlot(const std::vector<ScalingPoint>& points, const std::string& dir) {
  report::PlotOptions o;
  o.title = "memory as the scan goes on";
  o.x_label = "frames";
  o.y_label = "MiB";
  o.y_includes_zero = true;
  report::LinePlot plot(o);
  const std::pair<const char*, double ScalingPoint::*> series[] = {{"process RSS", &ScalingPoint::rss_mb},
                                                                  {"voxels active", &ScalingPoint::active_mb},
                                                                  {"voxels in host memory", &ScalingPoint::host_mb},
                                                                  {"voxels on disk", &ScalingPoint::disk_mb}};
  const char* colors[] = {"#000000", "#0072B2", "#009E73", "#D55E00"};
  for (size_t i = 0; i < 4; ++i) {
    report::Series line;
    line.name = series[i].first;
    line.color = colors[i];
    for (const ScalingPoint& p : points) {
      line.x.push_back(static_cast<double>(p.frames));
      line.y.push_back(p.*(series[i].second));
    }
    plot.add(std::move(line));
  }
  plot.save(dir + "/memory_plot.svg");
}

void writeCurve(const std::vector<ScalingPoint>& points, const std::string& dir, bool cpu_time) {
  std::ofstream csv(dir + "/scaling.csv", std::ios::trunc);
  csv << "frames,kf_keyframes,blocks,integrations,integration_ms,rounds,round_ms,round_blocks_updated,"
         "round_blocks_streamed,rss_mb,voxels_active_mb,voxels_host_mb,voxels_disk_mb\n";
  report::Series integration, round;
  integration.name = "first integration of a KF keyframe";
  round.name = "graph-update round (m KF keyframes)";
  integration.color = "#0072B2";
  round.color = "#D55E00";
  integration.markers = round.markers = true;
  for (const ScalingPoint& p : points) {
    csv << p.frames << ',' << p.kf_keyframes << ',' << p.blocks << ',' << p.integrations << ',' << p.integration_ms
        << ',' << p.rounds << ',' << p.round_ms << ',' << p.round_blocks_updated << ',' << p.round_blocks_streamed
        << ',' << p.rss_mb << ',' << p.active_mb << ',' << p.host_mb << ','
        << p.disk_mb << '\n';
    if (p.integrations > 0) integration.x.push_back(static_cast<double>(p.kf_keyframes)), integration.y.push_back(p.integration_ms);
    if (p.rounds > 0) round.x.push_back(static_cast<double>(p.kf_keyframes)), round.y.push_back(p.round_ms);
  }
  if (!csv) throw Error(dir + "/scaling.csv: cannot write; check that --out is writable");
  report::PlotOptions o;
  o.title = "integration and re-integration as the map grows";
  o.x_label = "KF keyframes in the map";
  o.y_label = cpu_time ? "ms CPU time (mean since the previous point)" : "ms wall time (mean since the previous point)";
  o.x_scale = o.y_scale = report::Scale::Log;
  report::LinePlot plot(o);
  plot.add(std::move(integration)).add(std::move(round));
  plot.save(dir + "/scaling_plot.svg");  // its data in scaling_plot.csv
  writeMemoryPlot(points, dir);
}

// Linux's peak resident memory of this process (VmHWM) in MiB, reset to now
// by the call, or -1 where /proc does not say.
double peakRssSinceLastCallMb() {
  const long long kb = procStatusKb("VmHWM");
  std::ofstream("/proc/self/clear_refs") << "5";
  return kb < 0 ? -1.0 : static_cast<double>(kb) / 1024.0;
}

// What the end of a run costs in memory beyond the map: the mesh written in
// pieces (the mapper's way) against the mesh held whole.
void measureMeshMemory(const mapper::Mapper& mapper, const std::string& dir) {
  const double rss = currentRssMb();
  peakRssSinceLastCallMb();
  const auto t0 = std::chrono::steady_clock::now();
  PlyWriter ply(dir + "/mesh.ply", true);
  mapper.extractMeshInPieces([&ply](const Mesh& piece) { ply.add(piece); });
  ply.finish();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double pieces_peak = peakRssSinceLastCallMb();
  const size_t whole_vertices = mapper.extractMesh().vertices.size();
  const double whole_peak = peakRssSinceLastCallMb();
  std::printf("%s\n", keyValueLine({{"mesh_vertices", static_cast<double>(ply.vertices())},
                                    {"mesh_s", seconds},
                                    {"mesh_in_pieces_extra_mb", pieces_peak - rss},
                                    {"mesh_whole_extra_mb", whole_peak - rss},
                                    {"mesh_whole_vertices", static_cast<double>(whole_vertices)}})
                          .c_str());
}

}  // namespace

int benchScalingCommand(int argc, char** argv) {
  ArgParser args(argv[0],
                 "Integration and re-integration time against the map's size on a synthetic scene rendered in process "
                 "(drifted poses, graph updates toward the ground truth as rekon-replay does). Writes scaling.csv and "
                 "scaling_plot.svg; the last line is first_*/last_* means over the first and last tenth of the points "
                 "(those with an integration, or a round).");
  args.option("out", "output folder")
      .option("scene", "synthetic scene (rekon synth --help)", "corridor")
      .option("laps", "corridor laps (3: 15 808 frames)", "3")
      .option("frames", "frames (0 = the scene's default for --laps)", "0")
      .option("level", "pyramid level rendered (0 = 640x480, 1 = 320x240)", "1")
      .option("every", "a point of the curve every this many frames", "500")
      .option("drift", "drift of the fused poses: metres per metre,degrees per metre", "0.03,1.5")
      .flag("wall", "time in wall clock instead of the process's CPU time")
      .flag("mesh", "at the end write OUT/mesh.ply in pieces and print the memory that took, and that of the mesh held whole")
      .option("config", "YAML file laid over config/default.yaml (volume and mapper settings)")
      .repeated("set", "override one key, e.g. --set mapper.m=5");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("out")) throw Error("--out is required; see rekon bench scaling --help");
  const Config config = Config::load(args.has("config") ? args.get("config") : "", args.all("set"));
  setupLogging("bench", config.getString("log.level"));
  const std::string out = args.get("out");
  createOutputFolder(out);
  const auto scene = synth::Scene::make(args.get("scene"));
  const int laps = args.getInt("laps");
  const int frames = args.getInt("frames") > 0 ? args.getInt("frames") : scene->defaultFrames(laps);
  const std::vector<double> drift = parseNumberList(args.get("drift"), "drift");
  if (drift.size() != 2) throw Error("--drift: give metres per metre and degrees per metre, e.g. 0.03,1.5");
  const Intrinsics k = synth::defaultIntrinsics().atLevel(args.getInt("level"));
  const Trajectory truth = scene->trajectory(frames, 1, laps);
  const Trajectory drifted = synth::driftedTrajectory(truth, drift[0], drift[1], 2);
  const int every = std::max(1, args.getInt("every"));

  mapper::MapperParams params = mapper::MapperParams::fromConfig(config);
  params.cpu_time_counters = !args.flagSet("wall");
  params.use_store = false;
  mapper::Mapper mapper(params);
  replay::ReplayParams rp;
  rp.trajectory = rp.target = "(in memory)";
  replay::ReplayScript script(drifted, truth, rp, frames);
  std::vector<ScalingPoint> points;
  Totals before;
  int64_t round_blocks_updated = 0;  // by the rounds' (de-)integrations, in total
  std::printf("frames kf_keyframes blocks integration_ms round_ms round_blocks_updated round_blocks_streamed (means since "
              "the previous line) rss_mb voxels_active_mb voxels_host_mb voxels_disk_mb\n");
  for (int i = 0; i < frames; ++i) {
    RgbdFrame f = scene->render(k, truth[static_cast<size_t>(i)].pose, synth::Noise::Kinect, static_cast<uint64_t>(i));
    f.id = i;
    f.timestamp = truth[static_cast<size_t>(i)].timestamp;
    const replay::ReplayTracked t = script.onFrame(f.id, f.timestamp);
    if (t.new_keyframe_world) mapper.setKeyframeEstimate(t.keyframe_id, *t.new_keyframe_world);
    mapper.addFrame(f, k, t.keyframe_id, t.pose_in_keyframe, t.lost);
    const int64_t updated_before = mapper.volume().stats().updated_blocks;
    if (mapper.correctionPending()) mapper.continueCorrection(false);  // mapper.round_budget_ms, as the worker does
    if (auto u = script.dueUpdate()) mapper.applyGraphUpdate(u->poses);
    round_blocks_updated += mapper.volume().stats().updated_blocks - updated_before;
    mapper.takeMeshChanges();  // as the service's mesh publisher does after each frame: the change set stays small
    if ((i + 1) % every == 0 || i + 1 == frames) {
      points.push_back(pointSince(before, mapper, round_blocks_updated));
      before = Totals::of(mapper.counters(), round_blocks_updated);
      const ScalingPoint& p = points.back();
      std::printf("%lld %lld %lld %.2f %.2f %.0f %.0f %.0f %.0f %.0f %.0f\n", static_cast<long long>(p.frames),
                  static_cast<long long>(p.kf_keyframes), static_cast<long long>(p.blocks), p.integration_ms, p.round_ms,
                  p.round_blocks_updated, p.round_blocks_streamed, p.rss_mb, p.active_mb, p.host_mb, p.disk_mb);
      std::fflush(stdout);
      writeCurve(points, out, params.cpu_time_counters);  // as it goes: a stopped run keeps its points
    }
  }
  // Means over the first and the last tenth of the points that have an
  // integration (or a round), so that one line says whether time grew with the map.
  auto ends = [&](int64_t ScalingPoint::*count, double ScalingPoint::*ms) {
    std::vector<double> v;
    for (const ScalingPoint& p : points)
      if (p.*count > 0) v.push_back(p.*ms);
    if (v.empty()) return std::make_pair(0.0, 0.0);
    const size_t tenth = std::max<size_t>(1, v.size() / 10);
    const auto mean = [&](size_t from) {
      double sum = 0.0;
      for (size_t i = from; i < from + tenth; ++i) sum += v[i];
      return sum / static_cast<double>(tenth);
    };
    return std::make_pair(mean(0), mean(v.size() - tenth));
  };
  const auto [first_integration, last_integration] = ends(&ScalingPoint::integrations, &ScalingPoint::integration_ms);
  const auto [first_round, last_round] = ends(&ScalingPoint::rounds, &ScalingPoint::round_ms);
  if (args.flagSet("mesh")) measureMeshMemory(mapper, out);
  std::printf("%s\n", keyValueLine({{"first_integration_ms", first_integration},
                                    {"last_integration_ms", last_integration},
                                    {"first_round_ms", first_round},
                                    {"last_round_ms", last_round},
                                    {"kf_keyframes", static_cast<double>(points.back().kf_keyframes)},
                                    {"blocks", static_cast<double>(points.back().blocks)}})
                          .c_str());
  return 0;
}

}  // namespace rekon::mapper_bench
