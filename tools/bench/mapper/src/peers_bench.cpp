// `rekon bench peers` (issue 19): the same frames integrated at the same
// settings by rekon's CPU backend, OpenCV's cv::kinfu hash TSDF volume and,
// when built with Debian's libopen3d-dev, Open3D 0.16's VoxelBlockGrid; ms per
// frame (wall and process CPU, every thread), the ratios, and how far each
// peer's surface lies from rekon's. Frames are decoded before any timing.
#include <opencv2/rgbd/volume.hpp>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "bench_data.hpp"
#include "peer_volumes.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/eval/surface_eval.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"
#include "rekon/mapper_bench/bench_command.hpp"

namespace rekon::mapper_bench {
namespace {

// A peer's surface against rekon's: distances (capped at 5 cm) from its points
// to rekon's mesh.
struct Agreement {
  double mean_mm = 0.0, median_mm = 0.0;
  double beyond_1cm = 0.0;  // fraction of its points farther than 1 cm
};

Agreement agreement(const std::vector<Eigen::Vector3f>& all_points, const Mesh& rekon_mesh) {
  Agreement a;
  if (all_points.empty()) return a;
  // Every k-th point, at most about 200 000: the statistics, not every point, are wanted.
  constexpr size_t kMaxPoints = 200000;
  const size_t step = (all_points.size() + kMaxPoints - 1) / kMaxPoints;
  std::vector<Eigen::Vector3f> points;
  for (size_t i = 0; i < all_points.size(); i += step) points.push_back(all_points[i]);
  std::vector<float> d = eval::distancesToSurface(points, rekon_mesh, 0.05);
  double sum = 0.0;
  size_t far = 0;
  for (float x : d) {
    sum += x;
    far += x > 0.01f;
  }
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
  a.mean_mm = 1e3 * sum / static_cast<double>(d.size());
  a.median_mm = 1e3 * d[d.size() / 2];
  a.beyond_1cm = static_cast<double>(far) / static_cast<double>(d.size());
  return a;
}

// rekon's TsdfVolume (CPU backend) over the frames, with or without color.
PeerRun runRekon(const BenchFrames& data, const PeerSettings& s, bool color) {
  volume::VolumeParams p;
  p.voxel_size = s.voxel_size;
  p.truncation = s.truncation;
  p.max_depth = s.max_depth;
  p.backend = "cpu";
  volume::TsdfVolume volume(p);
  std::vector<cv::Mat> metres;
  for (const RgbdFrame& f : data.frames) metres.push_back(volume::depthToMetres(f.depth, data.k.depth_scale));
  PeerRun r;
  r.name = color ? "rekon" : "rekon_depth_only";
  const PeerClock clock;
  for (size_t i = 0; i < data.frames.size(); ++i)
    volume.integrate(metres[i], color ? data.frames[i].color : cv::Mat(), cv::Mat(), data.k, data.poses[i]);
  clock.stop(data.frames.size(), r);
  r.surface = volume.extractMesh();
  return r;
}

// OpenCV's surface: its volume's fetchPointsNormals() returns every observed
// voxel of the truncation band, not the surface, and it has no mesh
// extraction; so the surface is what its own ray caster sees from every 10th
// integrated pose, in world coordinates.
std::vector<Eigen::Vector3f> raycastSurface(const cv::kinfu::Volume& volume, const std::vector<cv::Matx44f>& poses,
                                            const cv::kinfu::Intr& intr, cv::Size size) {
  std::vector<Eigen::Vector3f> surface;
  const size_t step = std::max<size_t>(1, poses.size() / 10);
  for (size_t i = 0; i < poses.size(); i += step) {
    cv::Mat points, normals;
    volume.raycast(poses[i], intr, size, points, normals);
    if (points.channels() < 3) throw Error("OpenCV's HashTSDF ray cast returned points with " +
                                           std::to_string(points.channels()) + " channels");
    const cv::Mat flat = points.reshape(1, static_cast<int>(points.total()));
    const cv::Matx44f& t = poses[i];
    for (int p = 0; p < flat.rows; ++p) {
      const cv::Vec4f c(flat.at<float>(p, 0), flat.at<float>(p, 1), flat.at<float>(p, 2), 1.0f);
      if (!std::isfinite(c[0]) || !std::isfinite(c[1]) || !std::isfinite(c[2]) || c[2] <= 0.0f) continue;
      const cv::Vec4f w = t * c;
      surface.emplace_back(w[0], w[1], w[2]);
    }
  }
  return surface;
}

// OpenCV 4.6's cv::kinfu HashTSDF volume (16^3 voxel units). It fuses no color.
PeerRun runOpenCv(const BenchFrames& data, const PeerSettings& s) {
  const cv::Ptr<cv::kinfu::VolumeParams> d = cv::kinfu::VolumeParams::defaultParams(cv::kinfu::VolumeType::HASHTSDF);
  const cv::Ptr<cv::kinfu::Volume> volume = cv::kinfu::makeVolume(
      cv::kinfu::VolumeType::HASHTSDF, static_cast<float>(s.voxel_size), cv::Matx44f::eye(), d->raycastStepFactor,
      static_cast<float>(s.truncation), d->maxWeight, static_cast<float>(s.max_depth), d->resolution);
  const cv::kinfu::Intr intr(static_cast<float>(data.k.fx), static_cast<float>(data.k.fy), static_cast<float>(data.k.cx),
                             static_cast<float>(data.k.cy));
  std::vector<cv::Matx44f> poses;
  for (const Pose& pose : data.poses) {
    cv::Matx44f m;
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) m(r, c) = static_cast<float>(pose.matrix()(r, c));
    poses.push_back(m);
  }
  std::vector<cv::Mat> depths(data.frames.size());  // its depth type: float, in the camera's depth units
  for (size_t i = 0; i < data.frames.size(); ++i) data.frames[i].depth.convertTo(depths[i], CV_32F);
  PeerRun r;
  r.name = "opencv_hashtsdf";
  const PeerClock clock;
  for (size_t i = 0; i < data.frames.size(); ++i)
    volume->integrate(depths[i], static_cast<float>(data.k.depth_scale), poses[i], intr, static_cast<int>(i));
  clock.stop(data.frames.size(), r);
  r.surface.vertices = raycastSurface(*volume, poses, intr, data.frames.front().depth.size());
  return r;
}

void print(const PeerRun& run, const PeerRun& rekon) {
  std::printf("%s_ms_per_frame=%.2f %s_cpu_ms_per_frame=%.2f %s_over_rekon=%.2f (cpu %.2f)", run.name.c_str(),
              run.ms_per_frame, run.name.c_str(), run.cpu_ms_per_frame, run.name.c_str(),
              run.ms_per_frame / rekon.ms_per_frame, run.cpu_ms_per_frame / rekon.cpu_ms_per_frame);
  if (&run != &rekon) {
    const Agreement a = agreement(run.surface.vertices, rekon.surface);
    std::printf(" %s_to_rekon_mean_mm=%.2f median_mm=%.2f beyond_1cm=%.3f points=%zu", run.name.c_str(), a.mean_mm,
                a.median_mm, a.beyond_1cm, run.surface.vertices.size());
  }
  std::printf("\n");
}

}  // namespace

int benchPeersCommand(int argc, char** argv) {
  ArgParser args("rekon bench peers",
                 "TSDF integration of the same frames by rekon, OpenCV's kinfu HashTSDF and Open3D's VoxelBlockGrid");
  args.option("dataset", "TUM dataset with groundtruth.txt (the poses integrated at)")
      .option("frames", "frames to use (0 = all)", "0")
      .option("voxel", "voxel size in metres", "0.01")
      .option("truncation", "truncation distance in metres", "0.04")
      .option("max-depth", "ignore depth beyond this many metres", "4.0")
      .option("out", "also write each surface here as PLY (OpenCV's as ray-cast points: its volume has no mesh extraction)");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("dataset")) throw Error("rekon bench peers: --dataset is required (see --help)");
  const std::string dataset = args.get("dataset");
  const BenchFrames data = loadFrames(dataset, dataset + "/groundtruth.txt", args.getInt("frames"), 1);
  PeerSettings s;
  s.voxel_size = args.getDouble("voxel");
  s.truncation = args.getDouble("truncation");
  s.max_depth = args.getDouble("max-depth");
  std::printf("dataset=%s frames=%zu voxel=%.3f truncation=%.3f max_depth=%.1f\n", dataset.c_str(), data.frames.size(),
              s.voxel_size, s.truncation, s.max_depth);
  std::vector<PeerRun> runs;
  runs.push_back(runRekon(data, s, true));
  runs.push_back(runRekon(data, s, false));
  runs.push_back(runOpenCv(data, s));
  if (std::optional<PeerRun> o3d = runOpen3d(data, s)) runs.push_back(std::move(*o3d));
  else std::printf("open3d: not built (install Debian's libopen3d-dev and configure again to compare in the same run)\n");
  for (const PeerRun& run : runs) print(run, runs.front());
  if (args.has("out")) {
    std::filesystem::create_directories(args.get("out"));
    for (const PeerRun& run : runs) writePly(run.surface, args.get("out") + "/" + run.name + ".ply");
  }
  return 0;
}

}  // namespace rekon::mapper_bench
