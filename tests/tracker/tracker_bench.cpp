// Benchmark of the tracker on a TUM-layout dataset: tracking time per frame
// (pyramid construction included, image decoding excluded), keyframes, lost
// frames, and ATE / RPE against the dataset's ground truth. Prints numbers;
// asserts nothing.
//   tracker_bench DATASET [FRAMES] [tracker.key=value ...]
#include <chrono>
#include <cstdio>
#include <iostream>
#include <string>
#include <vector>

#include "rekon/common/config.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/tracker/tracker.hpp"
#include "trajectory_metrics.hpp"

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
    const rekon::TumDataset dataset(argv[1], options);
    // Decode everything first so that the timed loop touches no disk.
    std::vector<rekon::RgbdFrame> frames;
    const auto l0 = std::chrono::steady_clock::now();
    for (size_t i = 0; i < dataset.size(); ++i) {
      frames.push_back(dataset.load(i));
      frames.back().id = static_cast<int64_t>(i);
    }
    const double load_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - l0).count() / frames.size();
    rekon::tracker::Tracker tracker(params);
    rekon::Trajectory trajectory;
    int lost = 0;
    double worst_ms = 0.0;
    const auto t0 = std::chrono::steady_clock::now();
    for (const auto& f : frames) {
      const auto a = std::chrono::steady_clock::now();
      const auto r = tracker.track(f, dataset.intrinsics());
      worst_ms = std::max(worst_ms, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count());
      lost += r.state == rekon::tracker::TrackingState::Lost;
      trajectory.push_back({f.timestamp, r.pose_world});
    }
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / frames.size();
    std::printf("frames=%zu keyframes=%lld lost=%d ms_per_frame=%.2f worst_ms=%.2f load_ms_per_frame=%.2f\n",
                frames.size(), static_cast<long long>(tracker.keyframeCount()), lost, ms, worst_ms, load_ms);
    if (dataset.hasGroundTruth()) {
      const auto e = rekon::tracker::test::compareTrajectories(trajectory, dataset.groundTruth());
      std::printf("matched=%d ate_rmse_cm=%.2f rpe_trans_cm_per_s=%.2f rpe_rot_deg_per_s=%.2f path_m=%.2f\n",
                  e.matched, 100 * e.ate_rmse_m, 100 * e.rpe_trans_m_per_s, e.rpe_rot_deg_per_s, e.path_length_m);
    }
    if (const char* out = std::getenv("TRACKER_BENCH_OUT")) rekon::writeTumTrajectory(trajectory, out);
  } catch (const rekon::Error& e) {
    std::cerr << "tracker_bench: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
