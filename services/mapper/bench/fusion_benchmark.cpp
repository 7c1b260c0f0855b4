// Speed of keyframe fusion on a real sequence with ground-truth poses: per
// frame add() (depth weights, warp, unsharp mask, blur metric) and per KF
// keyframe finish() (color fusion), wall and CPU time. Frames are decoded
// before timing. Not a test: it prints numbers.
//   rekon_fusion_benchmark [--dataset DIR] [--frames N] [--kappa K]
#include <opencv2/core/utility.hpp>
#include <spdlog/spdlog.h>

#include <chrono>
#include <vector>

#include "rekon/common/cli.hpp"
#include "rekon/common/cpu_time.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/common/memory.hpp"
#include "rekon/mapper/fusion/keyframe_fusion.hpp"

namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

}  // namespace

int main(int argc, char** argv) try {
  rekon::keepFreedMemory();
  rekon::setupLogging("fusion_benchmark", "info");
  rekon::ArgParser args("rekon_fusion_benchmark", "keyframe fusion speed (add per frame, finish per KF keyframe)");
  args.option("dataset", "TUM-layout dataset with groundtruth.txt", REKON_DEFAULT_DATASET)
      .option("frames", "frames to use (0 = all)", "200")
      .option("threads", "OpenCV threads of the color pass (0 = OpenCV's default)", "0")
      .option("kappa", "frames per KF keyframe", std::to_string(rekon::fusion::FusionParams::kDefaultKappa));
  if (!args.parse(argc, argv)) return 0;
  if (args.getInt("threads") > 0) cv::setNumThreads(args.getInt("threads"));
  rekon::DatasetOptions options;
  options.max_frames = args.getInt("frames");
  const rekon::TumDataset dataset(args.get("dataset"), options);
  if (!dataset.hasGroundTruth()) throw rekon::Error(args.get("dataset") + ": needs groundtruth.txt");
  std::vector<rekon::RgbdFrame> frames;
  std::vector<rekon::Pose> poses;
  for (size_t i = 0; i < dataset.size(); ++i) {
    const int p = rekon::nearestInTime(dataset.groundTruth(), dataset.timestamp(i), options.max_time_difference);
    if (p < 0) continue;
    frames.push_back(dataset.load(i));
    poses.push_back(dataset.groundTruth()[static_cast<size_t>(p)].pose);
  }
  rekon::fusion::FusionParams params;
  params.kappa = args.getInt("kappa");
  rekon::fusion::KeyframeFuser fuser(params, dataset.intrinsics());
  double add_wall = 0, add_cpu = 0, finish_wall = 0, finish_cpu = 0;
  int keyframes = 0;
  auto finish = [&] {
    const auto t = Clock::now();
    const double c = rekon::processCpuMs();
    fuser.finish();
    finish_wall += msSince(t);
    finish_cpu += rekon::processCpuMs() - c;
    ++keyframes;
  };
  for (size_t i = 0; i < frames.size(); ++i) {
    if (fuser.startsNewKeyframe(0, poses[i])) {
      if (fuser.active()) finish();
      fuser.begin(keyframes, 0, rekon::Pose::Identity(), poses[i]);
    }
    const auto t = Clock::now();
    const double c = rekon::processCpuMs();
    fuser.add(frames[i], poses[i]);
    add_wall += msSince(t);
    add_cpu += rekon::processCpuMs() - c;
  }
  if (fuser.active()) finish();
  const double n = static_cast<double>(frames.size());
  spdlog::info("{} frames, {} KF keyframes (kappa {})", frames.size(), keyframes, params.kappa);
  spdlog::info("add     {:.2f} ms wall, {:.2f} ms CPU per frame", add_wall / n, add_cpu / n);
  spdlog::info("finish  {:.1f} ms wall, {:.1f} ms CPU per KF keyframe", finish_wall / keyframes, finish_cpu / keyframes);
  spdlog::info("total   {:.2f} ms wall, {:.2f} ms CPU per frame", (add_wall + finish_wall) / n, (add_cpu + finish_cpu) / n);
  return 0;
} catch (...) {
  spdlog::error("{}", rekon::currentExceptionLine());
  return 1;
}
