#include "marching_cubes.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "parallel_for.hpp"

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
  int64_t offset = 0;
};

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
          auto mix = [&](int channel) {
            const float u = static_cast<float>(voxelColorFixed(a, channel)), v = static_cast<float>(voxelColorFixed(b, channel));
            return static_cast<uint8_t>(std::lround((u + t * (v - u)) / kColorScale));
          };
          out.edge.push_back(static_cast<uint16_t>(localIndex(x, y, z) * 3 + axis));
          out.position.push_back(p * voxel_size);
          out.color.push_back({mix(0), mix(1), mix(2)});
        }
      }
    }
  }
}

}  // namespace

const TriangleTable& triangleTable() {
  static const TriangleTable table = buildTable();
  return table;
}

Mesh marchingCubes(const std::vector<BlockCoord>& coords, const std::vector<const Voxel*>& blocks, float voxel_size,
                   float truncation) {
  const TriangleTable& table = triangleTable();
  Lookup lookup;
  uint32_t size = 1;
  while (size < 2 * coords.size() + 2) size <<= 1;
  lookup.entries.assign(size, HashEntry{{0, 0, 0}, kEmptySlot});
  for (size_t i = 0; i < coords.size(); ++i) {
    uint32_t h = hashBlock(coords[i]) & (size - 1);
    while (lookup.entries[h].slot != kEmptySlot) h = (h + 1) & (size - 1);
    lookup.entries[h] = {coords[i], static_cast<int32_t>(i)};
  }
  const int n = static_cast<int>(coords.size());
  constexpr int kGrain = 16;

  std::vector<BlockVertices> vertices(n);
  parallelFor(n, kGrain, 0, [&](int begin, int end, int) {
    Grid grid;
    for (int b = begin; b < end; ++b) {
      gatherGrid(lookup, blocks, coords[b], truncation, grid);
      makeVertices(grid, coords[b], voxel_size, vertices[b]);
    }
  });
  int64_t total = 0;
  for (auto& v : vertices) {
    v.offset = total;
    total += static_cast<int64_t>(v.edge.size());
  }

  std::vector<std::vector<Eigen::Vector3i>> triangles(n);
  parallelFor(n, kGrain, 0, [&](int begin, int end, int) {
    Grid grid;
    std::vector<int32_t> own(kBlockVoxels * 3);
    for (int b = begin; b < end; ++b) {
      const BlockCoord c = coords[b];
      const BlockVertices& mine = vertices[b];
      gatherGrid(lookup, blocks, c, truncation, grid);
      std::fill(own.begin(), own.end(), -1);
      for (size_t i = 0; i < mine.edge.size(); ++i) own[mine.edge[i]] = static_cast<int32_t>(i);
      const BlockVertices* neighbour[8] = {&mine};
      for (int k = 1; k < 8; ++k) {
        const int32_t idx = findBlock(lookup.view(), {c.x + (k & 1), c.y + ((k >> 1) & 1), c.z + ((k >> 2) & 1)});
        neighbour[k] = idx == kEmptySlot ? nullptr : &vertices[idx];
      }
      auto vertexOf = [&](int x, int y, int z, int axis) -> int64_t {
        const int k = (x == kBlockSide) | ((y == kBlockSide) << 1) | ((z == kBlockSide) << 2);
        const uint16_t edge = static_cast<uint16_t>(localIndex(x % kBlockSide, y % kBlockSide, z % kBlockSide) * 3 + axis);
        if (k == 0) return mine.offset + own[edge];
        const BlockVertices* nb = neighbour[k];
        const auto it = std::lower_bound(nb->edge.begin(), nb->edge.end(), edge);
        return nb->offset + (it - nb->edge.begin());
      };
      auto& out = triangles[b];
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
              Eigen::Vector3i tri;
              for (int j = 0; j < 3; ++j) {
                const int e = row[i + j];
                const int* o = kCorner[kEdgeCorners[e][0]];
                tri[j] = static_cast<int>(vertexOf(x + o[0], y + o[1], z + o[2], edgeAxis(e)));
              }
              out.push_back(tri);
            }
          }
        }
      }
    }
  });

  Mesh mesh;
  mesh.vertices.reserve(total);
  mesh.colors.reserve(total);
  for (const auto& v : vertices) {
    mesh.vertices.insert(mesh.vertices.end(), v.position.begin(), v.position.end());
    mesh.colors.insert(mesh.colors.end(), v.color.begin(), v.color.end());
  }
  size_t tri_total = 0;
  for (const auto& t : triangles) tri_total += t.size();
  mesh.triangles.reserve(tri_total);
  for (const auto& t : triangles) mesh.triangles.insert(mesh.triangles.end(), t.begin(), t.end());
  return mesh;
}

}  // namespace rekon::volume
