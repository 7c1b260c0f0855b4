#pragma once
// Every voxel of a volume by block coordinate: what the volume tests and the
// CUDA oracle compare between runs and backends.
#include <gtest/gtest.h>

#include <map>
#include <tuple>
#include <vector>

#include "rekon/mapper/volume/tsdf_volume.hpp"

namespace rekon::test {

using Snapshot = std::map<std::tuple<int, int, int>, std::vector<volume::Voxel>>;

inline Snapshot snapshot(const volume::TsdfVolume& volume) {
  Snapshot out;
  std::vector<volume::Voxel> voxels;
  for (const volume::BlockCoord& c : volume.blockCoords()) {
    EXPECT_TRUE(volume.readBlock(c, voxels));
    out[{c.x, c.y, c.z}] = voxels;
  }
  return out;
}

}  // namespace rekon::test
