// `rekon odometry` (commands.hpp).
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <iostream>

#include "commands.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/cpu_time.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/json.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/tracker.hpp"

namespace rekon {

using tracker::Tracker;
using tracker::TrackerParams;
using tracker::TrackingState;
using tracker::TrackResult;

int odometryCommand(int argc, char** argv) {
  ArgParser args(argv[0],
                 "Runs the DVO tracker in-process (no LCM) on a TUM-layout dataset and writes the world pose of "
                 "every frame as a TUM trajectory (the first keyframe at the origin). The last line printed is "
                 "ms_per_frame=... frames=... keyframes=..., where ms_per_frame is the wall time of tracking only "
                 "(pyramid construction included, image decoding excluded); the line before gives its CPU time "
                 "(cpu_ms_per_frame), the decoding time and the lost frames.");
  args.option("dataset", "dataset folder (rgb.txt, depth.txt, camera.yaml)")
      .option("out", "trajectory file to write")
      .option("frames", "track only the first N frames (0 = all)", "0")
      .option("config", "YAML file laid over config/default.yaml")
      .repeated("set", "override one key, e.g. --set tracker.finest_level=0");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("dataset")) throw Error("--dataset is required; give the folder of a TUM-layout sequence");
  if (!args.has("out")) throw Error("--out is required; give the trajectory file to write");
  const int max_frames = args.getInt("frames");
  if (max_frames < 0) throw Error("--frames must be 0 (all) or positive");

  const Config config = Config::load(args.has("config") ? args.get("config") : "", args.all("set"));
  setupLogging("odometry", config.getString("log.level"));
  const TrackerParams params = tracker::trackerParamsFromConfig(config);

  DatasetOptions options;
  options.max_frames = max_frames;
  const TumDataset dataset(args.get("dataset"), options);
  Tracker tracker(params);

  using Clock = std::chrono::steady_clock;
  double track_s = 0.0, load_s = 0.0, track_cpu_s = 0.0;
  size_t lost = 0;
  Trajectory trajectory;
  trajectory.reserve(dataset.size());
  for (size_t i = 0; i < dataset.size(); ++i) {
    const auto t0 = Clock::now();
    RgbdFrame frame = dataset.load(i);
    frame.id = static_cast<int64_t>(i);
    const auto t1 = Clock::now();
    const double c1 = threadCpuMs();
    const TrackResult result = tracker.track(frame, dataset.intrinsics());
    track_cpu_s += 1e-3 * (threadCpuMs() - c1);
    const auto t2 = Clock::now();
    load_s += std::chrono::duration<double>(t1 - t0).count();
    track_s += std::chrono::duration<double>(t2 - t1).count();
    if (result.state == TrackingState::Lost) ++lost;
    trajectory.push_back({frame.timestamp, result.pose_world});
    spdlog::debug("frame {} kf {} state {} iterations {} valid {} entropy {:.2f} ratio {:.3f} sigma {:.4f} {:.4f} m", i,
                  result.keyframe_id, result.state == TrackingState::Ok ? "ok" : tracker::toString(result.lost_reason),
                  result.iterations, result.valid_pixels, result.entropy, result.entropy_ratio, result.intensity_sigma,
                  result.depth_sigma);
  }
  writeTumTrajectory(trajectory, args.get("out"));
  const double n = static_cast<double>(std::max<size_t>(dataset.size(), 1));
  std::cout << keyValueLine({{"cpu_ms_per_frame", 1e3 * track_cpu_s / n},
                             {"load_ms_per_frame", 1e3 * load_s / n},
                             {"lost", static_cast<double>(lost)}})
            << "\n";
  std::cout << keyValueLine({{"ms_per_frame", 1e3 * track_s / n},
                             {"frames", static_cast<double>(dataset.size())},
                             {"keyframes", static_cast<double>(tracker.keyframeCount())}})
            << std::endl;
  return 0;
}

}  // namespace rekon
