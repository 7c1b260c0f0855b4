#pragma once
// `rekon bench longrun`: a long scan played through the real services (the
// building rendered on the fly by rekon-synth-source, or any dataset through
// rekon-player), live at 30 Hz or unpaced, measured as it goes, tabulated
// per minute, plotted, and judged against issue 49's goals.
#include <map>
#include <string>
#include <vector>

namespace rekon::longrun {

// One time bucket (a minute by default) of a run, from the tables the
// services and the bench write into the run folder. NaN where nothing was measured.
struct Bucket {
  double t0_s = 0;  // start, seconds of play
  double frames_due = 0, frames_sent = 0, frames_dropped = 0, frames_skipped = 0;
  double frames_posed = 0, frames_fused = 0;
  double latency_p50_ms, latency_p95_ms;
  double integrate_ms_mean, solve_ms_mean, solve_ms_max, round_ms_mean, round_ms_max;
  double loop_check_ms_mean;  // per keyframe checked, at the keyframe's frame
  double render_ms_mean;
  std::map<std::string, double> rss_mb;   // per service, the largest sample
  std::map<std::string, double> tier_mb;  // the mapper's voxels: active, host, on_disk (largest sample)
};

// Reads what a run folder holds (player_latency.csv, source_counts.csv,
// mapper_timing.csv, mapper_reintegration.csv, optimiser_timing.csv, tracker_loop_checks.csv,
// longrun_rss.csv, longrun_tiers.csv; any may be missing) into buckets of
// `bucket_s` seconds. `fps`: the frames' rate (frame id / fps = seconds of play).
std::vector<Bucket> readBuckets(const std::string& run_dir, double bucket_s, double fps);

// longrun.csv: one row per bucket.
void writeBucketsCsv(const std::vector<Bucket>& buckets, const std::string& path);

// The SVG plots (one per quantity, every bucket a point): the files written.
std::vector<std::string> writePlots(const std::vector<Bucket>& buckets, const std::string& dir);

// One goal of issue 49 judged on the buckets: "PASS", "FAIL" or "n/a" (no data).
struct GoalLine {
  std::string verdict, goal, measured;
};
// The windows scale with the run: for a run of D seconds, "minutes 1-10"
// is [D/60, D/6], "the last 10 minutes" [5D/6, D], "minute 10" [9D/60, D/6]
// and "minutes 5-15" [D/12, D/4]: the windows for a 60-minute run.
// `end_of_run_s`: from the source's end to the last service's exit (< 0: not known).
std::vector<GoalLine> judgeGoals(const std::vector<Bucket>& buckets, double bucket_s, double end_of_run_s);
// summary.txt: the goal lines (one each: "PASS|FAIL|n/a  goal: measured").
void writeSummary(const std::vector<GoalLine>& lines, const std::string& header, const std::string& path);

// `rekon bench longrun ...`
int benchLongrunCommand(int argc, char** argv);

}  // namespace rekon::longrun
