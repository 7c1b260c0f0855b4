#include "open3d_reference.hpp"

#include <open3d/core/Tensor.h>
#include <open3d/t/geometry/Image.h>
#include <open3d/t/geometry/TriangleMesh.h>
#include <open3d/t/geometry/VoxelBlockGrid.h>
#include <opencv2/imgproc.hpp>

#include <sys/resource.h>

#include <chrono>

namespace {

namespace o3c = open3d::core;
namespace o3g = open3d::t::geometry;

double cpuMs() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return (u.ru_utime.tv_sec + u.ru_stime.tv_sec) * 1e3 + (u.ru_utime.tv_usec + u.ru_stime.tv_usec) * 1e-3;
}

template <typename T>
o3g::Image toImage(const cv::Mat& m, o3c::Dtype dtype) {
  const T* p = m.ptr<T>();
  std::vector<T> values(p, p + m.total() * m.channels());
  return o3g::Image(o3c::Tensor(values, {m.rows, m.cols, m.channels()}, dtype));
}

}  // namespace

Open3dResult runOpen3dReference(const std::vector<cv::Mat>& depth_raw, const std::vector<cv::Mat>& color,
                                const std::vector<rekon::Pose>& poses, const rekon::Intrinsics& k, double voxel_size,
                                double truncation, double max_depth, bool float_voxels) {
  std::vector<o3g::Image> depths, colors;
  std::vector<o3c::Tensor> extrinsics;
  for (size_t i = 0; i < depth_raw.size(); ++i) {
    depths.push_back(toImage<uint16_t>(depth_raw[i], o3c::UInt16));
    cv::Mat rgb;
    cv::cvtColor(color[i], rgb, cv::COLOR_BGR2RGB);
    colors.push_back(toImage<uint8_t>(rgb, o3c::UInt8));
    const Eigen::Matrix4d w2c = poses[i].inverse().matrix();
    std::vector<double> e(16);
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) e[r * 4 + c] = w2c(r, c);
    }
    extrinsics.push_back(o3c::Tensor(e, {4, 4}, o3c::Float64));
  }
  const o3c::Tensor intrinsic(std::vector<double>{k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1}, {3, 3}, o3c::Float64);
  const o3c::Dtype small = float_voxels ? o3c::Float32 : o3c::UInt16;
  o3g::VoxelBlockGrid grid({"tsdf", "weight", "color"}, {o3c::Float32, small, small}, {{1}, {1}, {3}},
                           static_cast<float>(voxel_size), 8, 100000, o3c::Device("CPU:0"));
  const float trunc_multiplier = static_cast<float>(truncation / voxel_size);
  const float scale = static_cast<float>(k.depth_scale), depth_max = static_cast<float>(max_depth);
  auto t = std::chrono::steady_clock::now();
  const double cpu = cpuMs();
  for (size_t i = 0; i < depths.size(); ++i) {
    const o3c::Tensor blocks =
        grid.GetUniqueBlockCoordinates(depths[i], intrinsic, extrinsics[i], scale, depth_max, trunc_multiplier);
    grid.Integrate(blocks, depths[i], colors[i], intrinsic, extrinsics[i], scale, depth_max, trunc_multiplier);
  }
  Open3dResult r;
  r.integrate_ms_per_frame =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count() / depths.size();
  r.integrate_cpu_ms_per_frame = (cpuMs() - cpu) / depths.size();
  r.blocks = grid.GetHashMap().Size();
  t = std::chrono::steady_clock::now();
  const o3g::TriangleMesh mesh = grid.ExtractTriangleMesh(0.0f);
  r.mesh_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  r.mesh_vertices = static_cast<size_t>(mesh.GetVertexPositions().GetLength());
  return r;
}
