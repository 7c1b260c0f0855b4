// How large a TSDF map of a surface is: the voxel blocks within the
// truncation band of every triangle, counted without any map.
#include <cmath>
#include <unordered_set>

#include "rekon/common/error.hpp"
#include "rekon/synth/synth.hpp"

namespace rekon::synth {

int64_t surfaceBandBlocks(const Mesh& mesh, const BandOptions& o) {
  if (!(o.voxel_m > 0) || !(o.truncation_m >= 0) || o.block_voxels < 1)
    throw Error("surfaceBandBlocks: voxel size and block size must be positive, truncation non-negative");
  const double block = o.voxel_m * o.block_voxels;
  std::unordered_set<uint64_t> blocks;
  blocks.reserve(mesh.triangles.size());
  auto key = [](int64_t x, int64_t y, int64_t z) {  // 21 bits per axis: +-1 M blocks
    constexpr int64_t kOff = 1 << 20;
    return (static_cast<uint64_t>(x + kOff) << 42) | (static_cast<uint64_t>(y + kOff) << 21) | static_cast<uint64_t>(z + kOff);
  };
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices[static_cast<size_t>(t[0])].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[static_cast<size_t>(t[1])].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[static_cast<size_t>(t[2])].cast<double>();
    if ((a.z() + b.z() + c.z()) / 3.0 > o.max_z_m) continue;
    const Eigen::Vector3d n = (b - a).cross(c - a);
    if (n.squaredNorm() == 0) continue;
    // The triangle's box grown along each axis by the band's extent there:
    // exact for the axis-aligned faces that make up most scenes.
    const Eigen::Vector3d grow = o.truncation_m * n.normalized().cwiseAbs();
    const Eigen::Vector3d lo = a.cwiseMin(b).cwiseMin(c) - grow, hi = a.cwiseMax(b).cwiseMax(c) + grow;
    const Eigen::Vector3i l = (lo / block).array().floor().cast<int>(), h = (hi / block).array().floor().cast<int>();
    for (int x = l.x(); x <= h.x(); ++x)
      for (int y = l.y(); y <= h.y(); ++y)
        for (int z = l.z(); z <= h.z(); ++z) blocks.insert(key(x, y, z));
  }
  return static_cast<int64_t>(blocks.size());
}

}  // namespace rekon::synth
