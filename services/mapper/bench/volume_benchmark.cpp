// Speed of the TSDF volume on a real sequence with ground-truth poses:
// integration, de-integration (ms per frame) and marching cubes of the whole
// volume. Frames are decoded before timing. Not a test: it prints numbers.
// Against other libraries' volumes: `rekon bench peers` (tools/bench/mapper).
//   rekon_volume_benchmark [--dataset DIR] [--frames N] [--backend auto|cpu|cuda]
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "rekon/common/cli.hpp"
#include "rekon/common/cpu_time.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"

namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

struct Frame {
  cv::Mat depth, color;
  rekon::Pose pose;
};

// Every frame of the dataset that has a ground-truth pose, decoded up front.
std::vector<Frame> loadFrames(const rekon::TumDataset& dataset, double max_time_difference, bool no_color) {
  std::vector<Frame> frames;
  for (size_t i = 0; i < dataset.size(); ++i) {
    const int p = rekon::nearestInTime(dataset.groundTruth(), dataset.timestamp(i), max_time_difference);
    if (p < 0) continue;
    const rekon::RgbdFrame f = dataset.load(i);
    frames.push_back({rekon::volume::depthToMetres(f.depth, dataset.intrinsics().depth_scale),
                      no_color ? cv::Mat() : f.color, dataset.groundTruth()[p].pose});
  }
  return frames;
}

// Exactness on real data: A (first half) + B (second half) - B, B removed
// in a shuffled order, against A alone.
void printExactness(const std::vector<Frame>& frames, const rekon::volume::VolumeParams& params, const rekon::Intrinsics& k) {
  const size_t half = frames.size() / 2;
  rekon::volume::TsdfVolume a_only(params), a_plus_b(params);
  for (size_t i = 0; i < half; ++i) {
    a_only.integrate(frames[i].depth, frames[i].color, cv::Mat(), k, frames[i].pose);
    a_plus_b.integrate(frames[i].depth, frames[i].color, cv::Mat(), k, frames[i].pose);
  }
  std::vector<size_t> b;
  for (size_t i = half; i < frames.size(); ++i) {
    a_plus_b.integrate(frames[i].depth, frames[i].color, cv::Mat(), k, frames[i].pose);
    b.push_back(i);
  }
  for (size_t i = 0; i < b.size(); ++i) std::swap(b[i], b[(i * 7919 + 13) % b.size()]);
  for (size_t i : b) a_plus_b.deintegrate(frames[i].depth, frames[i].color, cv::Mat(), k, frames[i].pose);
  long long sdf = 0, weight = 0, color = 0, differing_color = 0, voxels = 0;
  std::vector<rekon::volume::Voxel> va, vb;
  const auto coords_a = a_only.blockCoords();
  for (const auto& c : coords_a) {
    a_only.readBlock(c, va);
    if (!a_plus_b.readBlock(c, vb)) {
      sdf = weight = -1;  // a block of A is missing
      break;
    }
    for (size_t i = 0; i < va.size(); ++i) {
      sdf = std::max<long long>(sdf, std::llabs(static_cast<long long>(va[i].sdf_sum) - vb[i].sdf_sum));
      using rekon::volume::voxelColor;
      using rekon::volume::voxelWeight;
      weight = std::max<long long>(weight, std::llabs(static_cast<long long>(voxelWeight(va[i])) - voxelWeight(vb[i])));
      int dc = 0;
      for (int ch = 0; ch < 3; ++ch) dc = std::max(dc, std::abs(voxelColor(va[i], ch) - voxelColor(vb[i], ch)));
      color = std::max<long long>(color, dc);
      differing_color += dc != 0;
      voxels += voxelWeight(va[i]) != 0;
    }
  }
  std::printf("exactness: A=%zu frames, B=%zu frames removed shuffled: blocks A=%zu A+B-B=%lld max_abs_diff sdf_sum=%lld "
              "weight=%lld color=%lld (levels; %lld of %lld observed voxels differ in color)\n",
              half, b.size(), coords_a.size(), static_cast<long long>(a_plus_b.stats().blocks), sdf, weight, color,
              differing_color, voxels);
}


}  // namespace

int main(int argc, char** argv) try {
  rekon::setupLogging("volume_benchmark", "info");
  rekon::ArgParser args("rekon_volume_benchmark", "TSDF integration / de-integration / meshing speed");
  args.option("dataset", "TUM-layout dataset with groundtruth.txt", REKON_DEFAULT_DATASET)
      .option("frames", "frames to use (0 = all)", "0")
      .option("backend", "auto, cpu or cuda", "auto")
      .option("threads", "CPU threads (0 = all)", "0")
      .flag("no-color", "integrate depth only (color left empty)")
      .option("stride", "allocation pixel stride", std::to_string(rekon::volume::VolumeParams::kDefaultAllocationStride));
  if (!args.parse(argc, argv)) return 0;
  rekon::DatasetOptions options;
  options.max_frames = args.getInt("frames");
  const rekon::TumDataset dataset(args.get("dataset"), options);
  if (!dataset.hasGroundTruth()) throw rekon::Error(args.get("dataset") + ": needs groundtruth.txt");
  const rekon::Intrinsics& k = dataset.intrinsics();

  const std::vector<Frame> frames = loadFrames(dataset, options.max_time_difference, args.flagSet("no-color"));
  spdlog::info("{} frames with poses loaded from {}", frames.size(), args.get("dataset"));

  rekon::volume::VolumeParams params;  // voxel 1 cm, truncation 4 cm, max depth 4 m
  params.backend = args.get("backend");
  params.cpu_threads = args.getInt("threads");
  params.allocation_stride = args.getInt("stride");
  rekon::volume::TsdfVolume volume(params);

  auto t = Clock::now();
  double cpu = rekon::processCpuMs();
  int64_t updated_blocks = 0;
  for (const Frame& f : frames) {
    volume.integrate(f.depth, f.color, cv::Mat(), k, f.pose);
    updated_blocks += volume.stats().last_update_blocks;
  }
  const double integrate_ms = msSince(t) / frames.size();
  const double integrate_cpu_ms = (rekon::processCpuMs() - cpu) / frames.size();
  const rekon::volume::VolumeStats s = volume.stats();

  t = Clock::now();
  const rekon::Mesh mesh = volume.extractMesh();
  const double mesh_s = msSince(t) / 1000.0;

  t = Clock::now();
  cpu = rekon::processCpuMs();
  const rekon::volume::RaycastImages ray = volume.raycast(k, frames.front().pose);
  const double raycast_ms = msSince(t), raycast_cpu_ms = rekon::processCpuMs() - cpu;
  int hits = 0;
  for (int v = 0; v < ray.depth.rows; ++v) {
    for (int u = 0; u < ray.depth.cols; ++u) hits += ray.depth.at<float>(v, u) > 0.f;
  }

  // De-integrate in reverse order: the volume must end empty.
  t = Clock::now();
  cpu = rekon::processCpuMs();
  for (auto it = frames.rbegin(); it != frames.rend(); ++it) volume.deintegrate(it->depth, it->color, cv::Mat(), k, it->pose);
  const double deintegrate_ms = msSince(t) / frames.size();
  const double deintegrate_cpu_ms = (rekon::processCpuMs() - cpu) / frames.size();

  std::printf("dataset=%s frames=%zu backend=%s voxel=%.3f truncation=%.3f max_depth=%.1f allocation_stride=%d\n",
              args.get("dataset").c_str(), frames.size(), s.backend.c_str(), params.voxel_size, params.truncation,
              params.max_depth, params.allocation_stride);
  std::printf("integrate_ms_per_frame=%.2f deintegrate_ms_per_frame=%.2f mesh_s=%.3f raycast_ms=%.1f\n", integrate_ms,
              deintegrate_ms, mesh_s, raycast_ms);
  std::printf("raycast_cpu_ms=%.1f raycast_hit_pixels=%d\n", raycast_cpu_ms, hits);
  std::printf("integrate_cpu_ms_per_frame=%.2f deintegrate_cpu_ms_per_frame=%.2f (all threads) blocks_per_frame=%.0f\n",
              integrate_cpu_ms, deintegrate_cpu_ms, static_cast<double>(updated_blocks) / frames.size());
  std::printf("blocks=%lld peak_active=%lld mesh_vertices=%zu mesh_triangles=%zu bytes_per_voxel=%d "
              "voxel_memory_mib=%.1f blocks_after_deintegration=%lld\n",
              static_cast<long long>(s.blocks), static_cast<long long>(s.peak_active_blocks), mesh.vertices.size(),
              mesh.triangles.size(), s.bytes_per_voxel,
              s.blocks * rekon::volume::kBlockVoxels * s.bytes_per_voxel / 1048576.0,
              static_cast<long long>(volume.stats().blocks));
  printExactness(frames, params, k);

  std::printf("peers: rekon bench peers --dataset DIR times OpenCV's and Open3D's volumes on the same frames\n");
  return 0;
} catch (...) {
  std::fprintf(stderr, "rekon_volume_benchmark: %s\n", rekon::currentExceptionLine().c_str());
  return 1;
}
