#include "bench_data.hpp"

#include <spdlog/spdlog.h>

#include <time.h>

#include <chrono>
#include <filesystem>
#include <sstream>

#include "rekon/common/cpu_time.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/tracker.hpp"

namespace rekon::mapper_bench {

BenchFrames loadFrames(const std::string& dataset_dir, const std::string& pose_file, int max_frames, int step) {
  if (step < 1) throw Error("--step must be at least 1 (every step-th frame is used)");
  if (max_frames < 0) throw Error("--frames must be 0 (all) or positive");
  const TumDataset dataset(dataset_dir);
  if (!std::filesystem::exists(pose_file))
    throw Error(pose_file + ": pose file not found; the dataset needs groundtruth.txt (or name the file with the option)");
  const Trajectory poses = readTumTrajectory(pose_file);
  BenchFrames out;
  out.k = dataset.intrinsics();
  for (size_t i = 0; i < dataset.size(); i += static_cast<size_t>(step)) {
    if (max_frames > 0 && static_cast<int>(out.frames.size()) >= max_frames) break;
    const int p = nearestInTime(poses, dataset.timestamp(i), DatasetOptions::kDefaultMaxTimeDifference);
    if (p < 0) {
      ++out.skipped_without_pose;
      continue;
    }
    RgbdFrame f = dataset.load(i);
    f.id = static_cast<int64_t>(out.frames.size());
    out.frames.push_back(std::move(f));
    out.poses.push_back(poses[static_cast<size_t>(p)].pose);
  }
  if (out.frames.empty())
    throw Error(dataset_dir + ": no frame has a pose in " + pose_file + " within 0.02 s; check the timestamps");
  spdlog::info("bench: {} frames of {} (every {}), {} without a pose skipped, {}x{}", out.frames.size(), dataset_dir,
               step, out.skipped_without_pose, out.k.width, out.k.height);
  return out;
}

double benchClockMs(bool cpu_time) {
  if (!cpu_time)
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
  return processCpuMs();
}

TrackingRun runTracker(const BenchFrames& data, const Config& config, bool cpu_time) {
  tracker::Tracker tracker(tracker::trackerParamsFromConfig(config));
  TrackingRun run;
  double total_ms = 0.0;
  for (const RgbdFrame& f : data.frames) {
    const double t0 = benchClockMs(cpu_time);
    const tracker::TrackResult r = tracker.track(f, data.k);
    total_ms += benchClockMs(cpu_time) - t0;
    run.keyframe_of_frame.push_back(std::max<int64_t>(0, r.keyframe_id));
    run.lost += r.state == tracker::TrackingState::Lost;
  }
  run.keyframes = tracker.keyframeCount();
  run.ms_per_frame = total_ms / static_cast<double>(data.frames.size());
  spdlog::info("bench: DVO tracker {:.1f} ms {} per frame, {} DVO keyframes, {} lost frames", run.ms_per_frame, cpu_time ? "CPU" : "wall",
               run.keyframes, run.lost);
  return run;
}

std::vector<double> parseNumberList(const std::string& text, const std::string& option) {
  std::vector<double> out;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');) {
    try {
      size_t used = 0;
      out.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw Error("--" + option + ": '" + item + "' is not a number; give a comma-separated list such as 1,2,5");
    }
  }
  return out;
}

std::vector<std::pair<double, double>> parsePairList(const std::string& text, const std::string& option) {
  std::vector<std::pair<double, double>> out;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');) {
    const size_t colon = item.find(':');
    if (colon == std::string::npos)
      throw Error("--" + option + ": '" + item + "' is not A:B; give a list such as 0.05:5,0.1:10");
    const auto a = parseNumberList(item.substr(0, colon), option), b = parseNumberList(item.substr(colon + 1), option);
    if (a.size() != 1 || b.size() != 1)
      throw Error("--" + option + ": '" + item + "' is not A:B; give a list such as 0.05:5,0.1:10");
    out.emplace_back(a[0], b[0]);
  }
  return out;
}

}  // namespace rekon::mapper_bench
