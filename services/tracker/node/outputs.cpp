#include "outputs.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include "rekon/common/error.hpp"
#include "rekon/common/pose.hpp"

namespace rekon::tracker {
namespace {

double percentile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  const size_t i = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size()))) - 1;
  const size_t k = std::min(i, values.size() - 1);
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

void writeTiming(const std::vector<std::pair<int64_t, double>>& frame_ms, const std::string& path) {
  std::ofstream out(path);
  out << "frame_id,ms\n";
  for (const auto& [id, ms] : frame_ms) out << id << ',' << ms << '\n';
  if (!out) throw Error("cannot write " + path + "; check that the output folder is writable");
}

}  // namespace

void writeOutputs(ServiceContext& ctx, const TrackingTotals& totals, int64_t frames_sent_again, double ack_held_s,
                  const LoopClosureStats& loops, const KeyframeCacheStats& keyframes, bool localise_only) {
  std::vector<double> ms;
  double ms_sum = 0.0;
  for (const auto& f : totals.frame_ms) {
    ms.push_back(f.second);
    ms_sum += f.second;
  }
  const double n = static_cast<double>(std::max<int64_t>(totals.frames, 1));
  ctx.stats()
      .set("frames", static_cast<long long>(totals.frames))
      .set("lost_frames", static_cast<long long>(totals.lost))
      .set("keyframes", static_cast<long long>(totals.keyframes))
      .set("keyframes_reused", static_cast<long long>(totals.keyframes_reused))
      .set("keyframe_reuse_checks", static_cast<long long>(totals.keyframe_reuse_checks))
      .set("odometry_constraints", static_cast<long long>(totals.constraints))
      .set("relocalisations", static_cast<long long>(totals.relocalisations))
      .set("undecodable_frames", static_cast<long long>(totals.undecodable))
      .set("frames_sent_again", static_cast<long long>(frames_sent_again))
      .set("track_cpu_ms_per_frame", 1e3 * totals.track_cpu_s / n)
      .set("ms_per_frame_mean", ms_sum / n)
      .set("ms_per_frame_p95", percentile(ms, 0.95))
      .set("loop_candidates", static_cast<long long>(loops.candidates))
      .set("loop_closures_accepted", static_cast<long long>(loops.accepted))
      .set("loop_closures_rejected", static_cast<long long>(loops.rejected))
      .set("loop_candidates_skipped", static_cast<long long>(loops.candidates_skipped))
      .set("loop_checks_behind", static_cast<long long>(loops.checks_behind))
      .set("loop_checks_dropped", static_cast<long long>(loops.checks_dropped))
      // tracker.loop_when_behind: hold: how long frame acknowledgements waited for the loop checks.
      .set("loop_acks_held_s", ack_held_s)
      .set("heap_trims", static_cast<long long>(loops.heap_trims))
      .set("loop_candidates_dropped", static_cast<long long>(loops.candidates_dropped))
      .set("loop_check_ms_per_keyframe",
           loops.check_ms / static_cast<double>(std::max<int64_t>(loops.keyframes_checked, 1)))
      // The DVO keyframes' tiers (tracker.keyframes_in_memory): resident now and at most, written to disk, read back.
      .set("keyframes_in_memory", static_cast<long long>(keyframes.resident))
      .set("keyframes_in_memory_peak", static_cast<long long>(keyframes.resident_peak))
      .set("keyframes_in_memory_mb", static_cast<double>(keyframes.resident_bytes) / (1024.0 * 1024.0))
      .set("keyframes_spilled", static_cast<long long>(keyframes.spilled))
      .set("keyframes_read_back", static_cast<long long>(keyframes.loaded));
  if (localise_only) {
    // What a localisation run gives: frames placed in the map, and how its keyframes were placed.
    ctx.stats()
        .set("localised_frames", static_cast<long long>(totals.localised.size()))
        .set("keyframes_placed_by_map", static_cast<long long>(totals.reanchored))
        .set("keyframes_placed_by_odometry",
             static_cast<long long>(totals.keyframes - totals.relocalisations - totals.reanchored));
  }
  LostIntervals lost = totals.lost_intervals;
  lost.finish();
  ctx.stats().set("lost_intervals_count", static_cast<long long>(lost.count())).setRaw("lost_intervals", lost.json());
  for (const LostInterval& i : lost.intervals()) {
    spdlog::info("lost from frame {} to {} ({} frames, {:.2f} s, {}): {}", i.first_frame, i.last_frame, i.frames, i.seconds,
                 i.reason, i.ended);
  }
  if (!ctx.outDir().empty()) {
    const std::string path = (std::filesystem::path(ctx.outDir()) / "odometry.txt").string();
    writeTumTrajectory(totals.odometry, path);
    spdlog::info("wrote {} odometry poses to {}", totals.odometry.size(), path);
    writeTiming(totals.frame_ms, (std::filesystem::path(ctx.outDir()) / "tracker_timing.csv").string());
    if (localise_only) {
      const std::string localised = (std::filesystem::path(ctx.outDir()) / "trajectory.txt").string();
      writeTumTrajectory(totals.localised, localised);
      spdlog::info("wrote {} poses in the session's map to {} ({} frames lost)", totals.localised.size(), localised,
                   totals.lost);
    }
  }
  spdlog::info("loop closures: {} candidates, {} accepted, {} rejected, {} checks dropped", loops.candidates,
               loops.accepted, loops.rejected, loops.checks_dropped);
  spdlog::info("tracked {} frames ({} lost), {} keyframes, {:.2f} ms CPU per frame", totals.frames, totals.lost,
               totals.keyframes, 1e3 * totals.track_cpu_s / n);
}

}  // namespace rekon::tracker
