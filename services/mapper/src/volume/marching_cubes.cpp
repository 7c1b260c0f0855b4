#include "marching_cubes.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <utility>

#include "parallel_for.hpp"
#include "rekon/common/error.hpp"

namespace rekon::volume {
namespace {

// Corner i of a cube at lattice offset kCorner[i]; edge e joins
// kEdgeCorners[e][0] (its lower end, which owns it) and kEdgeCorners[e][1].
constexpr int kCorner[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
constexpr int kEdgeCorners[12][2] = {{0, 1}, {1, 2}, {3, 2}, {0, 3}, {4, 5}, {5, 6},
                                     {7, 6}, {4, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}};
// Cube faces with corners counter-clockwise seen from outside.
constexpr int kFaces[6][4] = {{0, 3, 2, 1}, {4, 5, 6, 7}, {0, 1, 5, 4}, {3, 7, 6, 2}, {0, 4, 7, 3}, {1, 2, 6, 5}};

int edgeBetween(int a, int b) {
  for (int e = 0; e < 12; ++e) {
    if ((kEdgeCorners[e][0] == a && kEdgeCorners[e][1] == b) || (kEdgeCorners[e][0] == b && kEdgeCorners[e][1] == a)) return e;
  }
  return -1;
}

int edgeAxis(int e) {
  const int* a = kCorner[kEdgeCorners[e][0]];
  const int* b = kCorner[kEdgeCorners[e][1]];
  return b[0] != a[0] ? 0 : (b[1] != a[1] ? 1 : 2);
}

// Builds the table from the cube's faces instead of copying one: on each face
// the crossing edges are joined in pairs, each inside corner cut off on its
// own where a face is ambiguous (a rule both cubes sharing the face apply
// alike, so the surface is closed). The pairs chain into loops around the
// cube, which are fanned into triangles.
TriangleTable buildTable() {
  TriangleTable table{};
  for (int config = 0; config < 256; ++config) {
    auto inside = [&](int corner) { return (config >> corner) & 1; };
    int next[12];
    std::fill(next, next + 12, -1);
    for (const auto& face : kFaces) {
      for (int i = 0; i < 4; ++i) {
        const int a = face[i], b = face[(i + 1) % 4];
        if (!(inside(a) && !inside(b))) continue;
        int k = i;
        while (inside(face[(k + 3) % 4])) k = (k + 3) % 4;
        next[edgeBetween(a, b)] = edgeBetween(face[(k + 3) % 4], face[k]);
      }
    }
    int out = 0;
    bool visited[12] = {};
    for (int start = 0; start < 12; ++start) {
      if (next[start] < 0 || visited[start]) continue;
      int loop[12], n = 0;
      for (int e = start; !visited[e]; e = next[e]) {
        visited[e] = true;
        loop[n++] = e;
      }
      for (int t = 1; t + 1 < n; ++t) {
        table[config][out++] = static_cast<int8_t>(loop[0]);
        table[config][out++] = static_cast<int8_t>(loop[t]);
        table[config][out++] = static_cast<int8_t>(loop[t + 1]);
      }
    }
    table[config][out] = -1;
  }
  // Orient every triangle so its normal points from inside (negative) to
  // outside: check the single-inside-corner case and flip all if needed.
  auto midpoint = [](int e, int axis) {
    return 0.5f * (kCorner[kEdgeCorners[e][0]][axis] + kCorner[kEdgeCorners[e][1]][axis]);
  };
  const auto& t = table[1];
  float a[3], b[3];
  for (int i = 0; i < 3; ++i) {
    a[i] = midpoint(t[1], i) - midpoint(t[0], i);
    b[i] = midpoint(t[2], i) - midpoint(t[0], i);
  }
  const float n[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
  if (n[0] + n[1] + n[2] < 0.f) {  // corner 0 is inside; outside lies towards +x+y+z
    for (auto& row : table) {
      for (int i = 0; row[i] >= 0; i += 3) std::swap(row[i + 1], row[i + 2]);
    }
  }
  return table;
}

constexpr int kPad = kBlockSide + 1;  // a block plus the first layer of its +x/+y/+z neighbours
constexpr float kUnobserved = std::numeric_limits<float>::quiet_NaN();
constexpr int kGrain = 16;  // blocks per parallelFor task

struct Lookup {
  std::vector<HashEntry> entries;
  HashView view() const { return {entries.data(), static_cast<uint32_t>(entries.size() - 1)}; }
};

struct Grid {
  float sdf[kPad * kPad * kPad];
  const Voxel* voxel[kPad * kPad * kPad];
  static int index(int x, int y, int z) { return (z * kPad + y) * kPad + x; }
};

void gatherGrid(const Lookup& lookup, const std::vector<const Voxel*>& blocks, BlockCoord c, float truncation, Grid& g) {
  const Voxel* neighbour[8];
  for (int n = 0; n < 8; ++n) {
    const int32_t idx = findBlock(lookup.view(), {c.x + (n & 1), c.y + ((n >> 1) & 1), c.z + ((n >> 2) & 1)});
    neighbour[n] = idx == kEmptySlot ? nullptr : blocks[idx];
  }
  for (int z = 0; z < kPad; ++z) {
    for (int y = 0; y < kPad; ++y) {
      for (int x = 0; x < kPad; ++x) {
        const int n = (x == kBlockSide) | ((y == kBlockSide) << 1) | ((z == kBlockSide) << 2);
        const int i = Grid::index(x, y, z);
        const Voxel* v = neighbour[n] ? neighbour[n] + localIndex(x % kBlockSide, y % kBlockSide, z % kBlockSide) : nullptr;
        g.voxel[i] = (v && voxelWeight(*v)) ? v : nullptr;
        g.sdf[i] = g.voxel[i] ? voxelSdf(*v, truncation) : kUnobserved;
      }
    }
  }
}

struct BlockVertices {
  std::vector<uint16_t> edge;  // local voxel index * 3 + axis, ascending
  std::vector<Eigen::Vector3f> position;
  std::vector<std::array<uint8_t, 3>> color;
};

// The color at fraction t of the way from voxel a to voxel b, RGB.
std::array<uint8_t, 3> mixColor(const Voxel& a, const Voxel& b, float t) {
  auto mix = [&](int channel) {
    const float u = static_cast<float>(voxelColorFixed(a, channel)), v = static_cast<float>(voxelColorFixed(b, channel));
    return static_cast<uint8_t>(std::lround((u + t * (v - u)) / kColorScale));
  };
  return {mix(0), mix(1), mix(2)};
}

void makeVertices(const Grid& g, BlockCoord c, float voxel_size, BlockVertices& out) {
  for (int z = 0; z < kBlockSide; ++z) {
    for (int y = 0; y < kBlockSide; ++y) {
      for (int x = 0; x < kBlockSide; ++x) {
        const int i0 = Grid::index(x, y, z);
        const float s0 = g.sdf[i0];
        if (std::isnan(s0)) continue;
        for (int axis = 0; axis < 3; ++axis) {
          const int i1 = Grid::index(x + (axis == 0), y + (axis == 1), z + (axis == 2));
          const float s1 = g.sdf[i1];
          if (std::isnan(s1) || (s0 < 0.f) == (s1 < 0.f)) continue;
          const float t = s0 / (s0 - s1);
          Eigen::Vector3f p(static_cast<float>(c.x * kBlockSide + x), static_cast<float>(c.y * kBlockSide + y),
                            static_cast<float>(c.z * kBlockSide + z));
          p[axis] += t;
          const Voxel& a = *g.voxel[i0];
          const Voxel& b = *g.voxel[i1];
          out.edge.push_back(static_cast<uint16_t>(localIndex(x, y, z) * 3 + axis));
          out.position.push_back(p * voxel_size);
          out.color.push_back(mixColor(a, b, t));
        }
      }
    }
  }
}

// A vertex as the block that owns it (index into coords) and its index there.
struct VertexRef {
  int32_t block;
  int32_t index;
};
using TriangleRefs = std::vector<std::array<VertexRef, 3>>;

struct Lattice {
  Lookup lookup;
  std::vector<BlockVertices> vertices;  // per block of coords: the vertices it owns
};

// coords -> their index, as the kernels' open-addressing table.
Lookup makeLookup(const std::vector<BlockCoord>& coords) {
  Lookup lookup;
  uint32_t size = 1;
  while (size < 2 * coords.size() + 2) size <<= 1;
  lookup.entries.assign(size, HashEntry{{0, 0, 0}, kEmptySlot});
  for (size_t i = 0; i < coords.size(); ++i) {
    uint32_t h = hashBlock(coords[i]) & (size - 1);
    while (lookup.entries[h].slot != kEmptySlot) h = (h + 1) & (size - 1);
    lookup.entries[h] = {coords[i], static_cast<int32_t>(i)};
  }
  return lookup;
}

Lattice buildLattice(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks, float voxel_size,
                     float truncation, int max_workers) {
  Lattice lattice;
  lattice.lookup = makeLookup(coords);
  const int n = static_cast<int>(coords.size());
  lattice.vertices.resize(n);
  parallelFor(n, kGrain, max_workers, [&](int begin, int end, int) {
    Grid grid;
    for (int b = begin; b < end; ++b) {
      gatherGrid(lattice.lookup, blocks, coords[b], truncation, grid);
      makeVertices(grid, coords[b], voxel_size, lattice.vertices[b]);
    }
  });
  return lattice;
}

// The triangles of the cubes whose lower corner lies in block b; their
// vertices are owned by b or by its +x/+y/+z neighbours.
void blockTriangles(const Lattice& lattice, const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks,
                    int b, float truncation, Grid& grid, std::vector<int32_t>& own, TriangleRefs& out) {
  const TriangleTable& table = triangleTable();
  const BlockCoord c = coords[b];
  const BlockVertices& mine = lattice.vertices[b];
  gatherGrid(lattice.lookup, blocks, c, truncation, grid);
  std::fill(own.begin(), own.end(), -1);
  for (size_t i = 0; i < mine.edge.size(); ++i) own[mine.edge[i]] = static_cast<int32_t>(i);
  int32_t neighbour[8] = {b};
  for (int k = 1; k < 8; ++k) neighbour[k] = findBlock(lattice.lookup.view(), {c.x + (k & 1), c.y + ((k >> 1) & 1), c.z + ((k >> 2) & 1)});
  auto vertexOf = [&](int x, int y, int z, int axis) -> VertexRef {
    const int k = (x == kBlockSide) | ((y == kBlockSide) << 1) | ((z == kBlockSide) << 2);
    const uint16_t edge = static_cast<uint16_t>(localIndex(x % kBlockSide, y % kBlockSide, z % kBlockSide) * 3 + axis);
    if (k == 0) return {b, own[edge]};
    const BlockVertices& nb = lattice.vertices[neighbour[k]];
    const auto it = std::lower_bound(nb.edge.begin(), nb.edge.end(), edge);
    return {neighbour[k], static_cast<int32_t>(it - nb.edge.begin())};
  };
  for (int z = 0; z < kBlockSide; ++z) {
    for (int y = 0; y < kBlockSide; ++y) {
      for (int x = 0; x < kBlockSide; ++x) {
        int config = 0;
        bool observed = true;
        for (int k = 0; k < 8 && observed; ++k) {
          const float s = grid.sdf[Grid::index(x + kCorner[k][0], y + kCorner[k][1], z + kCorner[k][2])];
          observed = !std::isnan(s);
          config |= (s < 0.f) << k;
        }
        if (!observed || config == 0 || config == 255) continue;
        const auto& row = table[config];
        for (int i = 0; row[i] >= 0; i += 3) {
          std::array<VertexRef, 3> tri;
          for (int j = 0; j < 3; ++j) {
            const int e = row[i + j];
            const int* o = kCorner[kEdgeCorners[e][0]];
            tri[j] = vertexOf(x + o[0], y + o[1], z + o[2], edgeAxis(e));
          }
          out.push_back(tri);
        }
      }
    }
  }
}

// f(b, triangles of block b) for every b < count, on parallelFor's workers
// (max_workers as there; each has its own scratch grid).
template <class F>
void forEachBlockTriangles(const Lattice& lattice, const std::vector<BlockCoord>& coords,
                           const std::vector<const Voxel*>& blocks, int count, float truncation, int max_workers, F f) {
  parallelFor(count, kGrain, max_workers, [&](int begin, int end, int) {
    Grid grid;
    std::vector<int32_t> own(kBlockVoxels * 3);
    TriangleRefs refs;
    for (int b = begin; b < end; ++b) {
      refs.clear();
      blockTriangles(lattice, coords, blocks, b, truncation, grid, own, refs);
      f(b, refs);
    }
  });
}

// Block b's own mesh: every vertex it owns (in order), then those of its
// neighbours that its triangles use.
BlockMesh blockMesh(const Lattice& lattice, const std::vector<BlockCoord>& coords, int b, const TriangleRefs& refs) {
  BlockMesh out;
  out.x = coords[b].x;
  out.y = coords[b].y;
  out.z = coords[b].z;
  const BlockVertices& mine = lattice.vertices[b];
  out.vertices = mine.position;
  out.colors = mine.color;
  std::map<std::pair<int32_t, int32_t>, int> foreign;
  for (const auto& tri : refs) {
    Eigen::Vector3i t;
    for (int j = 0; j < 3; ++j) {
      const VertexRef r = tri[j];
      if (r.block == b) {
        t[j] = r.index;
        continue;
      }
      const auto [it, fresh] = foreign.try_emplace({r.block, r.index}, static_cast<int>(out.vertices.size()));
      if (fresh) {
        out.vertices.push_back(lattice.vertices[r.block].position[r.index]);
        out.colors.push_back(lattice.vertices[r.block].color[r.index]);
      }
      t[j] = it->second;
    }
    out.triangles.push_back(t);
  }
  return out;
}

// Block c's mesh at half resolution: marching cubes over every 2nd voxel
// (4^3 cubes of 2 voxels' edge, corners from the grid's 9^3 samples), each
// block on its own (its vertices on its +x/+y/+z faces are its own copies).
BlockMesh coarseBlockMesh(const Grid& g, BlockCoord c, float voxel_size) {
  constexpr int kStep = 2, kCells = kBlockSide / kStep, kPoints = kCells + 1;
  const TriangleTable& table = triangleTable();
  BlockMesh out;
  out.x = c.x;
  out.y = c.y;
  out.z = c.z;
  std::array<int32_t, kPoints * kPoints * kPoints * 3> made;  // coarse point * 3 + axis -> vertex, -1: none yet
  made.fill(-1);
  auto vertexOn = [&](int px, int py, int pz, int axis) {
    int32_t& slot = made[((pz * kPoints + py) * kPoints + px) * 3 + axis];
    if (slot >= 0) return slot;
    const int i0 = Grid::index(kStep * px, kStep * py, kStep * pz);
    const int i1 = Grid::index(kStep * (px + (axis == 0)), kStep * (py + (axis == 1)), kStep * (pz + (axis == 2)));
    const float t = g.sdf[i0] / (g.sdf[i0] - g.sdf[i1]);
    Eigen::Vector3f p(static_cast<float>(c.x * kBlockSide + kStep * px), static_cast<float>(c.y * kBlockSide + kStep * py),
                      static_cast<float>(c.z * kBlockSide + kStep * pz));
    p[axis] += kStep * t;
    slot = static_cast<int32_t>(out.vertices.size());
    out.vertices.push_back(p * voxel_size);
    out.colors.push_back(mixColor(*g.voxel[i0], *g.voxel[i1], t));
    return slot;
  };
  for (int z = 0; z < kCells; ++z) {
    for (int y = 0; y < kCells; ++y) {
      for (int x = 0; x < kCells; ++x) {
        int config = 0;
        bool observed = true;
        for (int k = 0; k < 8 && observed; ++k) {
          const float s = g.sdf[Grid::index(kStep * (x + kCorner[k][0]), kStep * (y + kCorner[k][1]), kStep * (z + kCorner[k][2]))];
          observed = !std::isnan(s);
          config |= (s < 0.f) << k;
        }
        if (!observed || config == 0 || config == 255) continue;
        const auto& row = table[config];
        for (int i = 0; row[i] >= 0; i += 3) {
          Eigen::Vector3i tri;
          for (int j = 0; j < 3; ++j) {
            const int e = row[i + j];
            const int* o = kCorner[kEdgeCorners[e][0]];
            tri[j] = vertexOn(x + o[0], y + o[1], z + o[2], edgeAxis(e));
          }
          out.triangles.push_back(tri);
        }
      }
    }
  }
  return out;
}

}  // namespace

std::vector<BlockMesh> marchingCubesCoarse(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks,
                                           int wanted, float voxel_size, float truncation) {
  const Lookup lookup = makeLookup(coords);
  std::vector<BlockMesh> out;
  out.reserve(wanted);
  Grid grid;
  for (int b = 0; b < wanted; ++b) {
    gatherGrid(lookup, blocks, coords[b], truncation, grid);
    out.push_back(coarseBlockMesh(grid, coords[b], voxel_size));
  }
  return out;
}

const TriangleTable& triangleTable() {
  static const TriangleTable table = buildTable();
  return table;
}

MeshPieces::MeshPieces(float voxel_size, float truncation) : voxel_size_(voxel_size), truncation_(truncation) {}

Mesh MeshPieces::next(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks, int wanted) {
  for (int b = 0; b < wanted; ++b) {
    if (coords[b].x > lowest_x_) throw Error("volume: internal error: mesh pieces out of order");
  }
  // Only the wanted blocks' vertices are complete (their +x/+y/+z neighbours
  // are in coords); the neighbours' were made when they were wanted.
  const Lattice lattice = buildLattice(coords, blocks, voxel_size_, truncation_, 0);
  Mesh piece;
  std::vector<int64_t> base(wanted);
  for (int b = 0; b < wanted; ++b) {
    const BlockVertices& v = lattice.vertices[b];
    base[b] = emitted_ + static_cast<int64_t>(piece.vertices.size());
    piece.vertices.insert(piece.vertices.end(), v.position.begin(), v.position.end());
    piece.colors.insert(piece.colors.end(), v.color.begin(), v.color.end());
  }
  auto globalIndex = [&](VertexRef r) -> int64_t {
    if (r.block < wanted) return base[r.block] + r.index;
    const auto owner = owners_.find(coords[r.block]);
    if (owner == owners_.end()) throw Error("volume: internal error: a mesh piece's neighbour was not meshed before it");
    const uint16_t edge = lattice.vertices[r.block].edge[r.index];
    const auto& edges = owner->second.edges;
    return owner->second.base + (std::lower_bound(edges.begin(), edges.end(), edge) - edges.begin());
  };
  std::vector<std::vector<Eigen::Vector3i>> triangles(wanted);
  forEachBlockTriangles(lattice, coords, blocks, wanted, truncation_, 0, [&](int b, const TriangleRefs& refs) {
    for (const auto& tri : refs) {
      Eigen::Vector3i t;
      for (int j = 0; j < 3; ++j) {
        const int64_t i = globalIndex(tri[j]);
        if (i > std::numeric_limits<int32_t>::max()) throw Error("volume: the mesh has over 2^31 vertices (PLY's int indices); mesh a part of the map");
        t[j] = static_cast<int32_t>(i);
      }
      triangles[b].push_back(t);
    }
  });
  for (const auto& t : triangles) piece.triangles.insert(piece.triangles.end(), t.begin(), t.end());
  // Remember the wanted blocks' vertices for the pieces to come, and forget
  // those no later piece can use: a block's vertices serve the cubes of its
  // own block and of its -x/-y/-z neighbours, so those with x above the
  // piece's lowest x + 1.
  int32_t lowest = lowest_x_;
  for (int b = 0; b < wanted; ++b) {
    owners_[coords[b]] = Owned{base[b], lattice.vertices[b].edge};
    lowest = std::min(lowest, coords[b].x);
  }
  lowest_x_ = lowest;
  for (auto it = owners_.begin(); it != owners_.end();) it = it->first.x > lowest_x_ + 1 ? owners_.erase(it) : std::next(it);
  emitted_ += static_cast<int64_t>(piece.vertices.size());
  return piece;
}

std::vector<BlockMesh> marchingCubesPerBlock(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks,
                                             int wanted, float voxel_size, float truncation, int max_workers) {
  const Lattice lattice = buildLattice(coords, blocks, voxel_size, truncation, max_workers);
  std::vector<BlockMesh> out(wanted);
  forEachBlockTriangles(lattice, coords, blocks, wanted, truncation, max_workers,
                        [&](int b, const TriangleRefs& refs) { out[b] = blockMesh(lattice, coords, b, refs); });
  return out;
}

}  // namespace rekon::volume
