#pragma once
// What both benches share: the frames of a dataset in memory with a pose for
// each, the DVO tracker run over them, option lists and the output folder.
#include <cstdint>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/rgbd_frame.hpp"

namespace rekon::mapper_bench {

struct BenchFrames {
  Intrinsics k;
  std::vector<RgbdFrame> frames;  // decoded, ids 0..n-1 in the order kept
  std::vector<Pose> poses;        // of each frame, from `pose_file`
  int skipped_without_pose = 0;
};

// Frames 0, step, 2 step, ... of the dataset (at most max_frames of them, 0 =
// all) that have a pose in pose_file within 0.02 s; decoding is done here so
// that no timing includes it. Throws rekon::Error when none is left.
BenchFrames loadFrames(const std::string& dataset, const std::string& pose_file, int max_frames, int step);

// The DVO tracker (services/tracker) over the frames, as rekon-tracker runs it.
struct TrackingRun {
  std::vector<int64_t> keyframe_of_frame;  // the DVO keyframe each frame was tracked against
  double ms_per_frame = 0.0;               // Tracker::track, CPU or wall time
  int64_t keyframes = 0;
  int64_t lost = 0;
};
TrackingRun runTracker(const BenchFrames& data, const Config& config, bool cpu_time);

// Milliseconds on the process CPU clock (every thread of this process; other
// processes on a shared machine do not inflate it) or the wall clock.
double benchClockMs(bool cpu_time);

// "1,2,5" -> {1, 2, 5}; throws rekon::Error naming the option for a bad entry.
std::vector<double> parseNumberList(const std::string& text, const std::string& option);
// "0.05:5,0.1:10" -> {{0.05, 5}, {0.1, 10}}.
std::vector<std::pair<double, double>> parsePairList(const std::string& text, const std::string& option);


}  // namespace rekon::mapper_bench
