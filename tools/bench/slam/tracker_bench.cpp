// Benchmark of the tracker on a TUM-layout dataset: tracking time per frame
// (pyramid construction included, image decoding excluded), keyframes, lost
// frames, and ATE / RPE against the dataset's ground truth. Prints numbers;
// asserts nothing.
//   tracker_bench DATASET [FRAMES] [tracker.key=value ...]
// DATASET synth:SCENE renders rekon_synth's SCENE with Kinect-like noise in
// process instead of reading a folder.
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include "rekon/common/config.hpp"
#include "rekon/common/cpu_time.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/slam_bench/trajectory_metrics.hpp"
#include "rekon/synth/synth.hpp"
#include "rekon/tracker/tracker.hpp"

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: tracker_bench DATASET [FRAMES] [tracker.key=value ...]\n";
    return 2;
  }
  try {
    std::vector<std::string> sets;
    for (int i = 3; i < argc; ++i) sets.emplace_back(argv[i]);
    const auto config = rekon::Config::load("", sets);
    const auto params = rekon::tracker::trackerParamsFromConfig(config);
    rekon::DatasetOptions options;
    options.max_frames = argc > 2 ? std::stoi(argv[2]) : 0;
    // Decode (or render) everything first so that the timed loop touches no disk.
    std::vector<rekon::RgbdFrame> frames;
    rekon::Intrinsics intrinsics;
    rekon::Trajectory ground_truth;
    const std::string source = argv[1];
    const auto l0 = std::chrono::steady_clock::now();
    if (source.rfind("synth:", 0) == 0) {
      const auto scene = rekon::synth::Scene::make(source.substr(6));
      intrinsics = rekon::synth::defaultIntrinsics();
      ground_truth = scene->trajectory(options.max_frames > 0 ? options.max_frames : scene->defaultFrames(), 1);
      for (size_t i = 0; i < ground_truth.size(); ++i) {
        frames.push_back(scene->render(intrinsics, ground_truth[i].pose, rekon::synth::Noise::Kinect, i + 1));
        frames.back().id = static_cast<int64_t>(i);
        frames.back().timestamp = ground_truth[i].timestamp;
      }
    } else {
      const rekon::TumDataset dataset(source, options);
      intrinsics = dataset.intrinsics();
      if (dataset.hasGroundTruth()) ground_truth = dataset.groundTruth();
      for (size_t i = 0; i < dataset.size(); ++i) {
        frames.push_back(dataset.load(i));
        frames.back().id = static_cast<int64_t>(i);
      }
    }
    const double load_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - l0).count() / frames.size();
    rekon::tracker::Tracker tracker(params);
    rekon::Trajectory trajectory;
    int lost = 0;
    double worst_ms = 0.0;
    long long iterations = 0;
    std::vector<double> sigma_i, sigma_z, ratios;
    // CPU time of this thread as well as wall time: other processes on a
    // shared machine inflate the wall time but not the thread's own CPU time.
    const double cpu0 = rekon::threadCpuMs();
    const auto t0 = std::chrono::steady_clock::now();
    for (const auto& f : frames) {
      const auto a = std::chrono::steady_clock::now();
      const auto r = tracker.track(f, intrinsics);
      worst_ms = std::max(worst_ms, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count());
      iterations += r.iterations;
      if (r.state == rekon::tracker::TrackingState::Ok && r.iterations > 0) {
        sigma_i.push_back(r.intensity_sigma);
        sigma_z.push_back(r.depth_sigma);
        ratios.push_back(r.entropy_ratio);
      }
      lost += r.state == rekon::tracker::TrackingState::Lost;
      trajectory.push_back({f.timestamp, r.pose_world});
    }
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / frames.size();
    const double cpu_ms = (rekon::threadCpuMs() - cpu0) / frames.size();
    std::printf(
        "frames=%zu keyframes=%lld lost=%d ms_per_frame=%.2f cpu_ms_per_frame=%.2f worst_ms=%.2f "
        "iterations_per_frame=%.1f load_ms_per_frame=%.2f\n",
        frames.size(), static_cast<long long>(tracker.keyframeCount()), lost, ms, cpu_ms, worst_ms,
        static_cast<double>(iterations) / frames.size(), load_ms);
    auto percentile = [](std::vector<double> v, double q) {
      if (v.empty()) return 0.0;
      std::sort(v.begin(), v.end());
      return v[static_cast<size_t>(q * (v.size() - 1))];
    };
    std::printf("intensity_sigma median=%.4f p99=%.4f max=%.4f  depth_sigma median=%.4f p99=%.4f max=%.4f\n",
                percentile(sigma_i, 0.5), percentile(sigma_i, 0.99), percentile(sigma_i, 1.0),
                percentile(sigma_z, 0.5), percentile(sigma_z, 0.99), percentile(sigma_z, 1.0));
    std::printf("entropy_ratio min=%.3f p01=%.3f median=%.3f\n", percentile(ratios, 0.0), percentile(ratios, 0.01),
                percentile(ratios, 0.5));
    if (!ground_truth.empty()) {
      const auto e = rekon::slam_bench::compareTrajectories(trajectory, ground_truth);
      std::printf(
          "matched=%d ate_rmse_cm=%.2f rpe_trans_cm_per_s=%.2f rpe_rot_deg_per_s=%.2f path_m=%.2f "
          "drift_percent=%.2f drift_deg_per_m=%.3f\n",
          e.matched, 100 * e.ate_rmse_m, 100 * e.rpe_trans_m_per_s, e.rpe_rot_deg_per_s, e.path_length_m,
          100 * e.drift_per_m, e.drift_deg_per_m);
    }
    if (const char* out = std::getenv("TRACKER_BENCH_OUT")) rekon::writeTumTrajectory(trajectory, out);
  } catch (const rekon::Error& e) {
    std::cerr << "tracker_bench: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
