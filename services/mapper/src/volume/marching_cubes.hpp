#pragma once
// Colored marching cubes over a set of voxel blocks. Vertices sit on voxel
// edges and each edge's vertex is made once (by the voxel at its lower end),
// so neighbouring cubes and blocks share it.
#include <array>
#include <cstdint>
#include <vector>

#include "rekon/common/mesh.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/mapper/volume/volume_kernels.hpp"

namespace rekon::volume {

// Triangles of each of the 256 inside/outside corner patterns, as edge
// numbers, -1 terminated. Corner i is inside when its signed distance is < 0.
using TriangleTable = std::array<std::array<int8_t, 37>, 256>;
const TriangleTable& triangleTable();

// blocks[i] holds kBlockVoxels voxels of block coords[i]; both from any store.
Mesh marchingCubes(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks, float voxel_size,
                   float truncation);

// The meshes of the first `wanted` blocks of coords, each on its own: the
// triangles of the cubes whose lower corner lies in it, every vertex it owns
// (as marchingCubes makes them, bit for bit) and then copies of the
// neighbours' vertices those triangles use. coords must hold the +x/+y/+z
// neighbours of the wanted blocks that exist (after them); versions are 0.
std::vector<BlockMesh> marchingCubesPerBlock(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks,
                                             int wanted, float voxel_size, float truncation);

// The meshes of the first `wanted` blocks of coords at half resolution:
// marching cubes over every 2nd voxel, about a quarter of the triangles, the
// same surface within a voxel or so; a preview that the full mesh replaces.
// Each block on its own: the vertices on its +x/+y/+z faces are its own
// copies (equal to its neighbours' coarse ones). coords as for
// marchingCubesPerBlock; versions are 0. On the calling thread.
std::vector<BlockMesh> marchingCubesCoarse(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks,
                                           int wanted, float voxel_size, float truncation);

}  // namespace rekon::volume
