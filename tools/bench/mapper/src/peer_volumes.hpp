#pragma once
// What `rekon bench peers` (peers_bench.cpp) measures of each TSDF volume,
// and Open3D's run (open3d_peer.cpp: compiled in only with libopen3d-dev).
#include <cstddef>
#include <optional>
#include <string>

#include "bench_data.hpp"
#include "rekon/common/mesh.hpp"

namespace rekon::mapper_bench {

struct PeerSettings {
  double voxel_size = 0.01, truncation = 0.04, max_depth = 4.0;
};

struct PeerRun {
  std::string name;
  double ms_per_frame = 0.0;      // wall
  double cpu_ms_per_frame = 0.0;  // process CPU, every thread (a spinning thread pool counts)
  Mesh surface;                   // its mesh, or its surface points (no triangles)
};

// Wall and process CPU time from construction to stop().
class PeerClock {
 public:
  PeerClock() : wall_(benchClockMs(false)), cpu_(benchClockMs(true)) {}
  void stop(size_t frames, PeerRun& r) const {
    r.ms_per_frame = (benchClockMs(false) - wall_) / static_cast<double>(frames);
    r.cpu_ms_per_frame = (benchClockMs(true) - cpu_) / static_cast<double>(frames);
  }

 private:
  double wall_, cpu_;
};

// Open3D 0.16's VoxelBlockGrid (8^3 blocks, float32 TSDF, uint16 weight and
// color: its SLAM layout) over the frames; nullopt when rekon was built
// without Open3D.
std::optional<PeerRun> runOpen3d(const BenchFrames& data, const PeerSettings& s);

}  // namespace rekon::mapper_bench
