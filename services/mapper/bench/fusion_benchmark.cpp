// Speed of keyframe fusion on a real sequence with ground-truth poses: per
// frame add() (depth weights, warp, unsharp mask, blur metric) and per KF
// keyframe finish() (color fusion), wall and CPU time. Frames are decoded
// before timing. Not a test: it prints numbers.
//   rekon_fusion_benchmark [--dataset DIR] [--frames N] [--kappa K] [--dump DIR] [--compare DIR]
// --dump writes each fused KF keyframe (depth, weight, color, raw) to DIR;
// --compare reads those written by another build and prints how this build's
// differ (depth and weight bit for bit, color per channel): a change to the
// fusion is checked against the version before it on real data.
#include <opencv2/core/utility.hpp>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstring>
#include <fstream>
#include <string>
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

// A fused KF keyframe's images, raw: depth and weight (float), then color (BGR bytes).
std::string keyframePath(const std::string& dir, int index) { return dir + "/kf_" + std::to_string(index) + ".bin"; }

void dumpKeyframe(const rekon::fusion::FusedKeyframe& kf, const std::string& path) {
  std::ofstream out(path, std::ios::binary);
  for (const cv::Mat* m : {&kf.depth, &kf.weight, &kf.color})
    out.write(reinterpret_cast<const char*>(m->data), static_cast<std::streamsize>(m->total() * m->elemSize()));
  if (!out) throw rekon::Error("cannot write " + path);
}

// How this build's keyframes differ from the ones dumped before, summed over keyframes.
struct Difference {
  size_t pixels = 0, depth_differ = 0, weight_differ = 0, color_differ = 0, colored = 0;
  int color_max = 0;
  double color_abs_sum = 0;
  double depth_max_m = 0, weight_max = 0;  // largest differences
  std::array<size_t, 4> by_max{};  // pixels whose largest channel difference is 1, 2-4, 5-16, > 16

  void add(const rekon::fusion::FusedKeyframe& kf, const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::vector<char> depth(kf.depth.total() * kf.depth.elemSize()), weight(depth.size()),
        color(kf.color.total() * kf.color.elemSize());
    for (std::vector<char>* v : {&depth, &weight, &color}) in.read(v->data(), static_cast<std::streamsize>(v->size()));
    if (!in) throw rekon::Error("cannot read " + path + " (written with --dump by a run of the same frames?)");
    const size_t n = kf.depth.total();
    pixels += n;
    for (size_t i = 0; i < n; ++i) {
      depth_differ += std::memcmp(depth.data() + 4 * i, kf.depth.data + 4 * i, 4) != 0;
      weight_differ += std::memcmp(weight.data() + 4 * i, kf.weight.data + 4 * i, 4) != 0;
      float dumped[2];
      std::memcpy(&dumped[0], depth.data() + 4 * i, 4);
      std::memcpy(&dumped[1], weight.data() + 4 * i, 4);
      depth_max_m = std::max(depth_max_m, static_cast<double>(std::abs(dumped[0] - kf.depth.ptr<float>()[i])));
      weight_max = std::max(weight_max, static_cast<double>(std::abs(dumped[1] - kf.weight.ptr<float>()[i])));
      int m = 0;
      for (size_t c = 0; c < 3; ++c) {
        const int d = std::abs(static_cast<int>(static_cast<uint8_t>(color[3 * i + c])) - kf.color.data[3 * i + c]);
        m = std::max(m, d);
        color_abs_sum += d;
      }
      colored += kf.color.data[3 * i] || kf.color.data[3 * i + 1] || kf.color.data[3 * i + 2];
      if (m == 0) continue;
      ++color_differ;
      color_max = std::max(color_max, m);
      ++by_max[m == 1 ? 0 : m <= 4 ? 1 : m <= 16 ? 2 : 3];
    }
  }
  void print() const {
    const double p = 100.0 / static_cast<double>(pixels);
    spdlog::info("compare: {} pixels ({} colored); depth differs at {} (at most {:.3g} m), weight at {} (at most {:.3g})",
                 pixels, colored, depth_differ, depth_max_m, weight_differ, weight_max);
    spdlog::info("compare: color differs at {} pixels ({:.4f} %), max channel difference {}, mean {:.6f} a channel",
                 color_differ, color_differ * p, color_max, color_abs_sum / (3.0 * static_cast<double>(pixels)));
    spdlog::info("compare: pixels whose largest channel difference is 1: {}, 2-4: {}, 5-16: {}, >16: {}", by_max[0],
                 by_max[1], by_max[2], by_max[3]);
  }
};

}  // namespace

int main(int argc, char** argv) try {
  rekon::keepFreedMemory();
  rekon::setupLogging("fusion_benchmark", "info");
  rekon::ArgParser args("rekon_fusion_benchmark", "keyframe fusion speed (add per frame, finish per KF keyframe)");
  args.option("dataset", "TUM-layout dataset with groundtruth.txt", REKON_DEFAULT_DATASET)
      .option("frames", "frames to use (0 = all)", "200")
      .option("threads", "OpenCV threads of the color pass (0 = OpenCV's default)", "0")
      .option("kappa", "frames per KF keyframe", std::to_string(rekon::fusion::FusionParams::kDefaultKappa))
      .option("dump", "write each fused KF keyframe's images to this folder", "")
      .option("compare", "compare each fused KF keyframe with the ones --dump wrote to this folder", "");
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
  Difference difference;
  auto finish = [&] {
    const auto t = Clock::now();
    const double c = rekon::processCpuMs();
    const rekon::fusion::FusedKeyframe kf = fuser.finish();
    finish_wall += msSince(t);
    finish_cpu += rekon::processCpuMs() - c;
    if (!args.get("dump").empty()) dumpKeyframe(kf, keyframePath(args.get("dump"), keyframes));
    if (!args.get("compare").empty()) difference.add(kf, keyframePath(args.get("compare"), keyframes));
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
  if (!args.get("compare").empty()) difference.print();
  return 0;
} catch (...) {
  spdlog::error("{}", rekon::currentExceptionLine());
  return 1;
}
