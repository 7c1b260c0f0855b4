#pragma once
// Colored marching cubes over a set of voxel blocks. Vertices sit on voxel
// edges and each edge's vertex is made once (by the voxel at its lower end),
// so neighbouring cubes and blocks share it.
#include <array>
#include <cstdint>
#include <limits>
#include <unordered_map>
#include <vector>

#include "rekon/common/mesh.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/mapper/volume/volume_kernels.hpp"

namespace rekon::volume {

// Triangles of each of the 256 inside/outside corner patterns, as edge
// numbers, -1 terminated. Corner i is inside when its signed distance is < 0.
using TriangleTable = std::array<std::array<int8_t, 37>, 256>;
const TriangleTable& triangleTable();

// Marching cubes over a map too large to hold its mesh and voxels at once,
// one piece of blocks at a time. Each piece is a mesh whose triangles index
// every vertex of the pieces before it and of itself (its own after theirs),
// so the pieces written one after the other are one mesh, the same surface as
// the whole map's. Pieces must come in descending (x, y, z) order of their
// blocks, each with its blocks' +x/+y/+z neighbours that exist after them (as
// for marchingCubesPerBlock): the neighbours were meshed in earlier pieces.
// What it keeps between pieces is the vertex numbering of the blocks at most
// one x above the last piece's lowest.
class MeshPieces {
 public:
  MeshPieces(float voxel_size, float truncation);
  // blocks[i] holds kBlockVoxels voxels of block coords[i]; the first `wanted` are meshed.
  Mesh next(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks, int wanted);

 private:
  struct CoordHash {
    size_t operator()(const BlockCoord& c) const { return hashBlock(c); }
  };
  struct Owned {
    int64_t base;                 // its first vertex's index in the mesh
    std::vector<uint16_t> edges;  // its vertices' edges (local voxel * 3 + axis), ascending
  };
  float voxel_size_, truncation_;
  int64_t emitted_ = 0;
  int32_t lowest_x_ = std::numeric_limits<int32_t>::max();
  std::unordered_map<BlockCoord, Owned, CoordHash> owners_;
};

// The meshes of the first `wanted` blocks of coords, each on its own: the
// triangles of the cubes whose lower corner lies in it, every vertex it owns
// (as marchingCubes makes them, bit for bit) and then copies of the
// neighbours' vertices those triangles use. coords must hold the +x/+y/+z
// neighbours of the wanted blocks that exist (after them); versions are 0.
// On up to max_workers of the pool's threads (1: the calling thread only).
std::vector<BlockMesh> marchingCubesPerBlock(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks,
                                             int wanted, float voxel_size, float truncation, int max_workers);

// The meshes of the first `wanted` blocks of coords at half resolution:
// marching cubes over every 2nd voxel, about a quarter of the triangles, the
// same surface within a voxel or so; a preview that the full mesh replaces.
// Each block on its own: the vertices on its +x/+y/+z faces are its own
// copies (equal to its neighbours' coarse ones). coords as for
// marchingCubesPerBlock; versions are 0. On the calling thread.
std::vector<BlockMesh> marchingCubesCoarse(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks,
                                           int wanted, float voxel_size, float truncation);

}  // namespace rekon::volume
