// odometry_cv_bench DATASET [FRAMES] [TRAJECTORY_OUT]: the OpenCV odometry
// in-process on a TUM-layout dataset (images decoded beforehand, not timed);
// prints CPU ms per frame and writes the world trajectory for `rekon eval
// traj`. With the dataset's groundtruth.txt it also checks the covariance:
// chi2 = xi^T C^-1 xi of each frame's error in its keyframe (xi = log of
// estimate^-1 * truth), whose mean is 6 for a calibrated covariance.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "rekon/common/cpu_time.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/odometry_cv/cv_odometry.hpp"

namespace {

// Ground-truth pose at `timestamp` (within 20 ms), or nullptr.
const rekon::Pose* truthAt(const rekon::Trajectory& truth, double timestamp) {
  const int i = rekon::nearestInTime(truth, timestamp, 0.02);
  return i < 0 ? nullptr : &truth[static_cast<size_t>(i)].pose;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: odometry_cv_bench DATASET [FRAMES] [TRAJECTORY_OUT]\n");
    return 2;
  }
  rekon::DatasetOptions options;
  options.max_frames = argc > 2 ? std::stoi(argv[2]) : 0;
  const rekon::TumDataset dataset(argv[1], options);
  const std::string gt_path = std::string(argv[1]) + "/groundtruth.txt";
  const rekon::Trajectory truth =
      std::filesystem::exists(gt_path) ? rekon::readTumTrajectory(gt_path) : rekon::Trajectory{};
  std::vector<rekon::RgbdFrame> frames;
  for (size_t i = 0; i < dataset.size(); ++i) frames.push_back(dataset.load(i));
  rekon::odometry_cv::CvOdometry odometry(dataset.intrinsics());
  rekon::Trajectory trajectory;
  std::vector<rekon::odometry_cv::CvTracked> tracked;
  int lost = 0;
  const double start = rekon::threadCpuMs();
  for (const auto& f : frames) tracked.push_back(odometry.track(f.depth, f.color));
  const double ms = (rekon::threadCpuMs() - start) / static_cast<double>(frames.size());
  std::vector<double> chi2;
  double keyframe_timestamp = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    const auto& t = tracked[i];
    if (t.new_keyframe) keyframe_timestamp = frames[i].timestamp;
    lost += t.lost;
    if (t.lost) continue;
    trajectory.push_back({frames[i].timestamp, rekon::orthonormalised(t.keyframe_world * t.pose_in_keyframe)});
    const rekon::Pose* kf = truthAt(truth, keyframe_timestamp);
    const rekon::Pose* now = truthAt(truth, frames[i].timestamp);
    if (t.new_keyframe || !kf || !now) continue;
    if (const auto c = rekon::odometry_cv::errorChi2(t.pose_in_keyframe, t.covariance, kf->inverse() * *now))
      chi2.push_back(*c);
  }
  if (argc > 3) rekon::writeTumTrajectory(trajectory, argv[3]);
  std::printf("frames=%zu keyframes=%zu lost=%d cpu_ms_per_frame=%.2f\n", frames.size(), odometry.keyframes().size(),
              lost, ms);
  if (!chi2.empty()) {
    std::sort(chi2.begin(), chi2.end());
    double sum = 0;
    for (double c : chi2) sum += c;
    std::printf("covariance check over %zu frames: chi2 mean %.1f, median %.1f (6 and 5.3 when calibrated)\n",
                chi2.size(), sum / static_cast<double>(chi2.size()), chi2[chi2.size() / 2]);
  }
  return 0;
}
