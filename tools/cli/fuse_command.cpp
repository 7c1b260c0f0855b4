// `rekon fuse` (commands.hpp).
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>

#include "commands.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"

namespace rekon {
namespace {

using volume::depthToMetres;
using volume::TsdfVolume;
using volume::VolumeParams;
using volume::VolumeStats;

}  // namespace

int fuseCommand(int argc, char** argv) {
  ArgParser args(argv[0], "Integrate a dataset at given poses into the TSDF volume and write its mesh");
  args.option("dataset", "TUM-layout dataset folder")
      .option("poses", "TUM trajectory (camera to world) to integrate at, e.g. DATASET/groundtruth.txt")
      .option("out", "output mesh (binary PLY)")
      .option("frames", "number of frames to integrate (0 = all)", "0")
      .option("voxel", "voxel size in metres", std::to_string(VolumeParams::kDefaultVoxelSize))
      .option("truncation", "truncation distance in metres", std::to_string(VolumeParams::kDefaultTruncation))
      .option("max-depth", "ignore depth beyond this many metres", std::to_string(VolumeParams::kDefaultMaxDepth))
      .option("streaming-radius", "keep blocks within this radius of the camera active (0 = all)", "0")
      .option("backend", "auto, cpu or cuda", "auto");
  if (!args.parse(argc, argv)) return 0;
  for (const char* required : {"dataset", "poses", "out"}) {
    if (!args.has(required)) throw Error(std::string("rekon fuse: --") + required + " is required (see --help)");
  }
  const int max_frames = args.getInt("frames");
  if (max_frames < 0) throw Error("rekon fuse: --frames must be >= 0 (0 = all)");

  DatasetOptions options;
  options.max_frames = max_frames;
  const TumDataset dataset(args.get("dataset"), options);
  const Trajectory poses = readTumTrajectory(args.get("poses"));
  if (poses.empty()) throw Error(args.get("poses") + ": no poses; pass a TUM trajectory");

  VolumeParams params;
  params.voxel_size = args.getDouble("voxel");
  params.truncation = args.getDouble("truncation");
  params.max_depth = args.getDouble("max-depth");
  params.streaming_radius = args.getDouble("streaming-radius");
  params.backend = args.get("backend");
  TsdfVolume volume(params);

  const Intrinsics& k = dataset.intrinsics();
  const size_t frames = max_frames > 0 ? std::min<size_t>(dataset.size(), max_frames) : dataset.size();
  double integrate_ms = 0.0;
  int integrated = 0, without_pose = 0;
  for (size_t i = 0; i < frames; ++i) {
    const int p = nearestInTime(poses, dataset.timestamp(i), options.max_time_difference);
    if (p < 0) {
      ++without_pose;
      continue;
    }
    const RgbdFrame frame = dataset.load(i);
    const auto start = std::chrono::steady_clock::now();
    const cv::Mat depth = depthToMetres(frame.depth, k.depth_scale);
    volume.streamAround(poses[p].pose.translation());
    volume.integrate(depth, frame.color, cv::Mat(), k, poses[p].pose);
    integrate_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    ++integrated;
  }
  if (integrated == 0) {
    throw Error("rekon fuse: no frame of " + args.get("dataset") + " has a pose in " + args.get("poses") +
                " within " + std::to_string(options.max_time_difference) + " s; check the trajectory's timestamps");
  }
  if (without_pose > 0) spdlog::warn("fuse: {} frame(s) had no pose within {} s and were skipped", without_pose, options.max_time_difference);

  const auto mesh_start = std::chrono::steady_clock::now();
  PlyWriter ply(args.get("out"), true);
  volume.extractMeshInPieces([&ply](const Mesh& piece) { ply.add(piece); });
  ply.finish();
  const double mesh_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - mesh_start).count();
  const VolumeStats s = volume.stats();
  spdlog::info("fuse: {} frames on the {} backend, mesh of {} vertices and {} triangles in {:.3f} s -> {}", integrated,
               s.backend, ply.vertices(), ply.faces(), mesh_s, args.get("out"));
  std::printf("ms_per_frame=%.2f blocks=%lld bytes_per_voxel=%d\n", integrate_ms / integrated,
              static_cast<long long>(s.blocks), s.bytes_per_voxel);
  return 0;
}

}  // namespace rekon
