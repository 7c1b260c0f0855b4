// odometry_cv_bench DATASET [FRAMES] [TRAJECTORY_OUT]: the OpenCV odometry
// in-process on a TUM-layout dataset (images decoded beforehand, not timed);
// prints CPU ms per frame and writes the world trajectory for `rekon eval traj`.
#include <cstdio>
#include <string>

#include "rekon/common/cpu_time.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/odometry_cv/cv_odometry.hpp"

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: odometry_cv_bench DATASET [FRAMES] [TRAJECTORY_OUT]\n");
    return 2;
  }
  rekon::DatasetOptions options;
  options.max_frames = argc > 2 ? std::stoi(argv[2]) : 0;
  const rekon::TumDataset dataset(argv[1], options);
  std::vector<rekon::RgbdFrame> frames;
  for (size_t i = 0; i < dataset.size(); ++i) frames.push_back(dataset.load(i));
  rekon::odometry_cv::CvOdometry odometry(dataset.intrinsics());
  rekon::Trajectory trajectory;
  int lost = 0;
  const double start = rekon::threadCpuMs();
  for (const auto& f : frames) {
    const auto t = odometry.track(f.depth, f.color);
    lost += t.lost;
    if (!t.lost) trajectory.push_back({f.timestamp, rekon::orthonormalised(t.keyframe_world * t.pose_in_keyframe)});
  }
  const double ms = (rekon::threadCpuMs() - start) / static_cast<double>(frames.size());
  if (argc > 3) rekon::writeTumTrajectory(trajectory, argv[3]);
  std::printf("frames=%zu keyframes=%zu lost=%d cpu_ms_per_frame=%.2f\n", frames.size(), odometry.keyframes().size(),
              lost, ms);
  return 0;
}
