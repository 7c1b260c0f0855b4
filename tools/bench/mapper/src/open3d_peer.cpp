// Open3D's VoxelBlockGrid for `rekon bench peers` (peer_volumes.hpp). Built
// with Open3D only when CMake finds it (Debian's libopen3d-dev); without it
// runOpen3d says so by returning nothing.
#include "peer_volumes.hpp"

#ifdef REKON_WITH_OPEN3D
#include <open3d/core/Tensor.h>
#include <open3d/t/geometry/Image.h>
#include <open3d/t/geometry/TriangleMesh.h>
#include <open3d/t/geometry/VoxelBlockGrid.h>
#include <opencv2/imgproc.hpp>

namespace rekon::mapper_bench {
namespace {

namespace o3c = open3d::core;
namespace o3g = open3d::t::geometry;

template <typename T>
o3g::Image toImage(const cv::Mat& m, o3c::Dtype dtype) {
  const T* p = m.ptr<T>();
  std::vector<T> values(p, p + m.total() * m.channels());
  return o3g::Image(o3c::Tensor(values, {m.rows, m.cols, m.channels()}, dtype));
}

o3c::Tensor worldToCamera(const Pose& pose) {
  const Eigen::Matrix4d w2c = pose.inverse().matrix();
  std::vector<double> e(16);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) e[r * 4 + c] = w2c(r, c);
  return o3c::Tensor(e, {4, 4}, o3c::Float64);
}

}  // namespace

std::optional<PeerRun> runOpen3d(const BenchFrames& data, const PeerSettings& s) {
  std::vector<o3g::Image> depths, colors;
  std::vector<o3c::Tensor> extrinsics;
  for (size_t i = 0; i < data.frames.size(); ++i) {
    depths.push_back(toImage<uint16_t>(data.frames[i].depth, o3c::UInt16));
    cv::Mat rgb;
    cv::cvtColor(data.frames[i].color, rgb, cv::COLOR_BGR2RGB);
    colors.push_back(toImage<uint8_t>(rgb, o3c::UInt8));
    extrinsics.push_back(worldToCamera(data.poses[i]));
  }
  const Intrinsics& k = data.k;
  const o3c::Tensor intrinsic(std::vector<double>{k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1}, {3, 3}, o3c::Float64);
  o3g::VoxelBlockGrid grid({"tsdf", "weight", "color"}, {o3c::Float32, o3c::UInt16, o3c::UInt16}, {{1}, {1}, {3}},
                           static_cast<float>(s.voxel_size), 8, 100000, o3c::Device("CPU:0"));
  const float trunc_multiplier = static_cast<float>(s.truncation / s.voxel_size);
  const float scale = static_cast<float>(k.depth_scale), depth_max = static_cast<float>(s.max_depth);
  PeerRun r;
  r.name = "open3d";
  const PeerClock clock;
  for (size_t i = 0; i < depths.size(); ++i) {
    const o3c::Tensor blocks =
        grid.GetUniqueBlockCoordinates(depths[i], intrinsic, extrinsics[i], scale, depth_max, trunc_multiplier);
    grid.Integrate(blocks, depths[i], colors[i], intrinsic, extrinsics[i], scale, depth_max, trunc_multiplier);
  }
  clock.stop(depths.size(), r);
  const o3c::Tensor positions = grid.ExtractTriangleMesh(0.0f).GetVertexPositions().To(o3c::Float32).Contiguous();
  const float* p = positions.GetDataPtr<float>();
  for (int64_t i = 0; i < positions.GetLength(); ++i) r.surface.vertices.emplace_back(p[3 * i], p[3 * i + 1], p[3 * i + 2]);
  return r;
}

}  // namespace rekon::mapper_bench
#else
namespace rekon::mapper_bench {

std::optional<PeerRun> runOpen3d(const BenchFrames&, const PeerSettings&) { return std::nullopt; }

}  // namespace rekon::mapper_bench
#endif
