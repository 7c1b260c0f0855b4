// Benchmark of the tracker on a TUM-layout dataset: tracking time per frame
// (pyramid construction included, image decoding excluded), keyframes, lost
// frames, and ATE / RPE against the dataset's ground truth. Prints numbers;
// asserts nothing.
//   tracker_bench DATASET [FRAMES] [tracker.key=value ...]
// DATASET synth:SCENE renders rekon_synth's SCENE with Kinect-like noise in
// process instead of reading a folder. TRACKER_BENCH_OUT=FILE writes the
// trajectory.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/cpu_time.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/rgbd_frame.hpp"
#include "rekon/slam_bench/trajectory_metrics.hpp"
#include "rekon/synth/synth.hpp"
#include "rekon/tracker/tracker.hpp"

namespace rekon::slam_bench {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

// Every frame decoded (or rendered) first, so that the timed loop touches no disk.
struct Input {
  std::vector<RgbdFrame> frames;
  Intrinsics intrinsics;
  Trajectory ground_truth;
  double load_ms_per_frame = 0.0;
};

Input load(const std::string& source, int max_frames) {
  Input in;
  const auto l0 = Clock::now();
  if (source.rfind("synth:", 0) == 0) {
    const auto scene = synth::Scene::make(source.substr(6));
    in.intrinsics = synth::defaultIntrinsics();
    in.ground_truth = scene->trajectory(max_frames > 0 ? max_frames : scene->defaultFrames(), 1);
    for (size_t i = 0; i < in.ground_truth.size(); ++i) {
      in.frames.push_back(scene->render(in.intrinsics, in.ground_truth[i].pose, synth::Noise::Kinect, i + 1));
      in.frames.back().id = static_cast<int64_t>(i);
      in.frames.back().timestamp = in.ground_truth[i].timestamp;
    }
  } else {
    DatasetOptions options;
    options.max_frames = max_frames;
    const TumDataset dataset(source, options);
    in.intrinsics = dataset.intrinsics();
    if (dataset.hasGroundTruth()) in.ground_truth = dataset.groundTruth();
    for (size_t i = 0; i < dataset.size(); ++i) {
      in.frames.push_back(dataset.load(i));
      in.frames.back().id = static_cast<int64_t>(i);
    }
  }
  in.load_ms_per_frame = msSince(l0) / in.frames.size();
  return in;
}

struct Run {
  Trajectory trajectory;
  int64_t keyframes = 0;
  int lost = 0;
  double ms_per_frame = 0.0, cpu_ms_per_frame = 0.0, worst_ms = 0.0;
  long long iterations = 0;
  std::vector<double> intensity_sigma, depth_sigma, entropy_ratio;  // of the frames aligned and not lost
};

Run trackAll(const Input& in, const tracker::TrackerParams& params) {
  tracker::Tracker tracker(params);
  Run run;
  // CPU time of this thread as well as wall time: other processes on a
  // shared machine inflate the wall time but not the thread's own CPU time.
  const double cpu0 = threadCpuMs();
  const auto t0 = Clock::now();
  for (const auto& f : in.frames) {
    const auto a = Clock::now();
    const auto r = tracker.track(f, in.intrinsics);
    run.worst_ms = std::max(run.worst_ms, msSince(a));
    run.iterations += r.iterations;
    if (r.state == tracker::TrackingState::Ok && r.iterations > 0) {
      run.intensity_sigma.push_back(r.intensity_sigma);
      run.depth_sigma.push_back(r.depth_sigma);
      run.entropy_ratio.push_back(r.entropy_ratio);
    }
    run.lost += r.state == tracker::TrackingState::Lost;
    run.trajectory.push_back({f.timestamp, r.pose_world});
  }
  run.ms_per_frame = msSince(t0) / in.frames.size();
  run.cpu_ms_per_frame = (threadCpuMs() - cpu0) / in.frames.size();
  run.keyframes = tracker.keyframeCount();
  return run;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[static_cast<size_t>(q * (v.size() - 1))];
}

void print(const Input& in, const Run& run) {
  const size_t n = in.frames.size();
  std::printf(
      "frames=%zu keyframes=%lld lost=%d ms_per_frame=%.2f cpu_ms_per_frame=%.2f worst_ms=%.2f "
      "iterations_per_frame=%.1f load_ms_per_frame=%.2f\n",
      n, static_cast<long long>(run.keyframes), run.lost, run.ms_per_frame, run.cpu_ms_per_frame, run.worst_ms,
      static_cast<double>(run.iterations) / n, in.load_ms_per_frame);
  const auto& si = run.intensity_sigma;
  const auto& sz = run.depth_sigma;
  std::printf("intensity_sigma median=%.4f p99=%.4f max=%.4f  depth_sigma median=%.4f p99=%.4f max=%.4f\n",
              percentile(si, 0.5), percentile(si, 0.99), percentile(si, 1.0), percentile(sz, 0.5),
              percentile(sz, 0.99), percentile(sz, 1.0));
  std::printf("entropy_ratio min=%.3f p01=%.3f median=%.3f\n", percentile(run.entropy_ratio, 0.0),
              percentile(run.entropy_ratio, 0.01), percentile(run.entropy_ratio, 0.5));
  if (in.ground_truth.empty()) return;
  const auto e = compareTrajectories(run.trajectory, in.ground_truth);
  std::printf(
      "matched=%d ate_rmse_cm=%.2f rpe_trans_cm_per_s=%.2f rpe_rot_deg_per_s=%.2f path_m=%.2f "
      "drift_percent=%.2f drift_deg_per_m=%.3f\n",
      e.matched, 100 * e.ate_rmse_m, 100 * e.rpe_trans_m_per_s, e.rpe_rot_deg_per_s, e.path_length_m,
      100 * e.drift_per_m, e.drift_deg_per_m);
}

}  // namespace
}  // namespace rekon::slam_bench

int main(int argc, char** argv) {
  using namespace rekon::slam_bench;
  if (argc < 2) {
    std::cerr << "usage: tracker_bench DATASET [FRAMES] [tracker.key=value ...]\n";
    return 2;
  }
  try {
    std::vector<std::string> sets;
    for (int i = 3; i < argc; ++i) sets.emplace_back(argv[i]);
    const auto params = rekon::tracker::trackerParamsFromConfig(rekon::Config::load("", sets));
    const Input in = load(argv[1], argc > 2 ? std::stoi(argv[2]) : 0);
    const Run run = trackAll(in, params);
    print(in, run);
    if (const char* out = std::getenv("TRACKER_BENCH_OUT")) rekon::writeTumTrajectory(run.trajectory, out);
  } catch (const rekon::Error& e) {
    std::cerr << "tracker_bench: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
