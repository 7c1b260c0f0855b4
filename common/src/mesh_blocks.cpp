#include "rekon/common/mesh_blocks.hpp"

#include <fmt/format.h>

#include <spdlog/fmt/fmt.h>

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <future>
#include <iterator>
#include <set>
#include <string>
#include <unordered_map>

#include "rekon/common/bus.hpp"
#include "rekon/common/error.hpp"

namespace rekon {
namespace {

constexpr int kMaxBlockVertices = 65535;  // indices travel as uint16
constexpr size_t kVertexBytes = 3 * 2 + 3;  // uint16 x, y, z and RGB
constexpr size_t kTriangleBytes = 3 * 2;
constexpr double kExpectedMeshCompression = 1.5;  // zlib level 1 on 7-Scenes' block meshes: 1.53
constexpr size_t kMinBlocksPerThread = 1000;  // ~1 MB raw: fewer are not worth a thread

std::string coordText(int32_t x, int32_t y, int32_t z) { return fmt::format("({}, {}, {})", x, y, z); }

void putU16(std::vector<uint8_t>& out, uint32_t v) {
  out.push_back(static_cast<uint8_t>(v & 0xff));
  out.push_back(static_cast<uint8_t>(v >> 8));
}

uint16_t getU16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }

size_t rawBytes(const BlockMesh& b) { return b.vertices.size() * kVertexBytes + b.triangles.size() * kTriangleBytes; }

void checkEncodable(const BlockMesh& b) {
  const std::string where = "mesh block " + coordText(b.x, b.y, b.z);
  if (b.vertices.size() > static_cast<size_t>(kMaxBlockVertices)) {
    throw Error(where + " has " + std::to_string(b.vertices.size()) + " vertices; at most 65535 fit its uint16 indices");
  }
  if (b.colors.size() != b.vertices.size()) {
    throw Error(where + " has " + std::to_string(b.colors.size()) + " colors for " + std::to_string(b.vertices.size()) + " vertices");
  }
  if (b.vertices.empty() && !b.triangles.empty()) throw Error(where + " has triangles but no vertices");
}

// Quanta from the block's lower corner, taken from the global lattice of
// quanta so that every block rounds a shared vertex alike.
void putVertices(const BlockMesh& b, const MeshBlocksParams& p, std::vector<uint8_t>& raw) {
  const double per_metre = 1.0 / p.quantum();
  const int64_t block_quanta = static_cast<int64_t>(p.block_voxels) * p.quanta_per_voxel;
  const int64_t corner[3] = {b.x * block_quanta, b.y * block_quanta, b.z * block_quanta};
  for (const Eigen::Vector3f& v : b.vertices) {
    for (int i = 0; i < 3; ++i) {
      const int64_t q = std::llround(static_cast<double>(v[i]) * per_metre) - corner[i];
      if (!std::isfinite(v[i]) || q < 0 || q > 0xffff) {
        throw Error("mesh block " + coordText(b.x, b.y, b.z) + ": vertex coordinate " + std::to_string(v[i]) +
                    " m lies outside the block's 16-bit range of quanta");
      }
      putU16(raw, static_cast<uint32_t>(q));
    }
  }
  for (const auto& c : b.colors) raw.insert(raw.end(), c.begin(), c.end());
}

void putTriangles(const BlockMesh& b, std::vector<uint8_t>& raw) {
  for (const Eigen::Vector3i& t : b.triangles) {
    for (int i = 0; i < 3; ++i) {
      if (t[i] < 0 || static_cast<size_t>(t[i]) >= b.vertices.size()) {
        throw Error("mesh block " + coordText(b.x, b.y, b.z) + ": triangle index " + std::to_string(t[i]) + " out of range");
      }
      putU16(raw, static_cast<uint32_t>(t[i]));
    }
  }
}

std::vector<uint8_t> deflateBytes(const std::vector<uint8_t>& raw, int level) {
  uLongf size = compressBound(static_cast<uLong>(raw.size()));
  std::vector<uint8_t> out(size);
  if (compress2(out.data(), &size, raw.data(), static_cast<uLong>(raw.size()), level) != Z_OK) {
    throw Error("mesh blocks: zlib could not compress " + std::to_string(raw.size()) + " bytes");
  }
  out.resize(size);
  return out;
}

rekon_msgs::mesh_blocks_t makeMessage(const std::vector<BlockMesh>& blocks, size_t begin, size_t end,
                                      const MeshBlocksParams& p) {
  rekon_msgs::mesh_blocks_t m{};
  m.schema_version = kSchemaVersion;
  m.voxel_size = p.voxel_size;
  m.block_voxels = p.block_voxels;
  m.quantum = p.quantum();
  std::vector<uint8_t> raw;
  for (size_t i = begin; i < end; ++i) {
    const BlockMesh& b = blocks[i];
    m.blocks.push_back({b.x, b.y, b.z, b.version, static_cast<int32_t>(b.vertices.size()),
                        static_cast<int32_t>(b.triangles.size()), static_cast<int8_t>(b.cause)});
    putVertices(b, p, raw);
    putTriangles(b, raw);
  }
  m.num_blocks = static_cast<int32_t>(m.blocks.size());
  m.raw_size = static_cast<int32_t>(raw.size());
  m.payload = deflateBytes(raw, p.zlib_level);
  m.payload_size = static_cast<int32_t>(m.payload.size());
  return m;
}

size_t encodedSize(const rekon_msgs::mesh_blocks_t& m) { return static_cast<size_t>(m.getEncodedSize()); }

// Blocks [begin, end) as messages that fit: a run whose message is too big is halved.
void encodeRun(const std::vector<BlockMesh>& blocks, size_t begin, size_t end, const MeshBlocksParams& p,
               std::vector<rekon_msgs::mesh_blocks_t>& out) {
  rekon_msgs::mesh_blocks_t m = makeMessage(blocks, begin, end, p);
  if (encodedSize(m) <= p.max_message_bytes) {
    out.push_back(std::move(m));
    return;
  }
  if (end - begin == 1) {
    const BlockMesh& b = blocks[begin];
    throw Error("mesh block " + coordText(b.x, b.y, b.z) + " alone needs " + std::to_string(encodedSize(m)) +
                " bytes, more than the message limit of " + std::to_string(p.max_message_bytes) +
                "; raise mapper.mesh_max_message_bytes");
  }
  const size_t mid = begin + (end - begin) / 2;
  encodeRun(blocks, begin, mid, p, out);
  encodeRun(blocks, mid, end, p, out);
}

// Raw bytes per payload byte of out's messages from `first` on (1 for none).
double compressionOf(const std::vector<rekon_msgs::mesh_blocks_t>& out, size_t first) {
  double raw = 0.0, payload = 0.0;
  for (size_t i = first; i < out.size(); ++i) {
    raw += out[i].raw_size;
    payload += out[i].payload_size;
  }
  return payload > 0.0 ? std::max(1.0, raw / payload) : 1.0;
}

// Blocks [begin, end) in runs whose raw bytes should compress to 90 % of
// the limit at the ratio the last run got (a run that does not fit is halved
// and each half compressed again, so the runs must fit the first time: zlib
// got 1.53:1 on 7-Scenes' meshes, where runs sized for 2:1 were all halved
// and the final update spent 320 ms compressing 9.3 MB twice).
void encodeSlice(const std::vector<BlockMesh>& blocks, size_t begin, size_t end, const MeshBlocksParams& params,
                 std::vector<rekon_msgs::mesh_blocks_t>& out) {
  double ratio = kExpectedMeshCompression;
  size_t run_begin = begin, run_bytes = 0;
  for (size_t i = begin; i < end; ++i) {
    const size_t bytes = rawBytes(blocks[i]) + sizeof(rekon_msgs::mesh_block_t);
    if (i > run_begin && static_cast<double>(run_bytes + bytes) > 0.9 * ratio * static_cast<double>(params.max_message_bytes)) {
      const size_t first = out.size();
      encodeRun(blocks, run_begin, i, params, out);
      ratio = compressionOf(out, first);
      run_begin = i;
      run_bytes = 0;
    }
    run_bytes += bytes;
  }
  if (run_begin < end) encodeRun(blocks, run_begin, end, params, out);
}

void checkParams(const MeshBlocksParams& p) {
  if (!(p.voxel_size > 0.0) || p.block_voxels < 1 || p.quanta_per_voxel < 1 ||
      2LL * p.block_voxels * p.quanta_per_voxel > 0xffff + 1) {
    throw Error("mesh blocks: voxel_size " + fmt::format("{}", p.voxel_size) + ", block_voxels " +
                std::to_string(p.block_voxels) + " and quanta_per_voxel " + std::to_string(p.quanta_per_voxel) +
                " do not fit 16-bit coordinates (2 * block_voxels * quanta_per_voxel must be at most 65536)");
  }
}

}  // namespace

std::vector<rekon_msgs::mesh_blocks_t> encodeMeshBlocks(const std::vector<BlockMesh>& blocks,
                                                        const MeshBlocksParams& params, int64_t sequence, bool full,
                                                        int threads) {
  checkParams(params);
  for (const BlockMesh& b : blocks) checkEncodable(b);
  // Contiguous slices, one a thread (the caller's the first), so the parts keep the blocks' order.
  const size_t slices = std::clamp<size_t>(static_cast<size_t>(std::max(threads, 1)), 1,
                                           std::max<size_t>(1, blocks.size() / kMinBlocksPerThread));
  std::vector<std::vector<rekon_msgs::mesh_blocks_t>> sliced(slices);
  auto encode = [&](size_t s) {
    encodeSlice(blocks, blocks.size() * s / slices, blocks.size() * (s + 1) / slices, params, sliced[s]);
  };
  std::vector<std::future<void>> helpers;
  for (size_t s = 1; s < slices; ++s) helpers.push_back(std::async(std::launch::async, encode, s));
  encode(0);
  for (auto& h : helpers) h.get();  // a helper's error is thrown here
  std::vector<rekon_msgs::mesh_blocks_t> out;
  for (auto& part : sliced) std::move(part.begin(), part.end(), std::back_inserter(out));
  if (out.empty()) encodeRun(blocks, 0, 0, params, out);  // nothing to send still says so (an empty map's snapshot)
  for (size_t i = 0; i < out.size(); ++i) {
    out[i].sequence = sequence;
    out[i].part = static_cast<int32_t>(i);
    out[i].parts = static_cast<int32_t>(out.size());
    out[i].full = full;
  }
  return out;
}

namespace {

void checkHeader(const rekon_msgs::mesh_blocks_t& m) {
  auto bad = [](const std::string& what) { throw Error("mesh_blocks_t: " + what + "; message dropped"); };
  if (!(std::isfinite(m.voxel_size) && m.voxel_size > 1e-5 && m.voxel_size <= 10.0)) bad("voxel_size is not in (1e-5, 10] m");
  if (m.block_voxels < 1 || m.block_voxels > 256) bad("block_voxels " + std::to_string(m.block_voxels) + " is not in [1, 256]");
  if (!(std::isfinite(m.quantum) && m.quantum > 0.0 && m.quantum <= m.voxel_size)) bad("quantum is not in (0, voxel_size]");
  if (m.parts < 1 || m.parts > kMaxMeshParts || m.part < 0 || m.part >= m.parts) {
    bad("part " + std::to_string(m.part) + " of " + std::to_string(m.parts) + " is impossible");
  }
  if (m.raw_size < 0 || m.raw_size > kMaxMeshRawBytes) {
    bad("raw_size " + std::to_string(m.raw_size) + " is not in [0, " + std::to_string(kMaxMeshRawBytes) + "]");
  }
  if (m.num_blocks != static_cast<int32_t>(m.blocks.size()) || m.payload_size != static_cast<int32_t>(m.payload.size())) {
    bad("array counts disagree with the arrays");
  }
  int64_t expected = 0;
  std::set<std::tuple<int32_t, int32_t, int32_t>> seen;
  for (const auto& b : m.blocks) {
    const std::string where = "block " + coordText(b.bx, b.by, b.bz);
    for (int32_t c : {b.bx, b.by, b.bz}) {
      if (c < -kMaxMeshBlockCoord || c > kMaxMeshBlockCoord) bad(where + " lies absurdly far away");
    }
    if (b.version < 0) bad(where + " has a negative version");
    if (b.cause < 0 || b.cause > kMaxBlockCause) bad(where + " has an unknown cause " + std::to_string(b.cause));
    if (b.num_vertices < 0 || b.num_vertices > kMaxBlockVertices || b.num_triangles < 0 ||
        b.num_triangles > kMaxMeshRawBytes / static_cast<int32_t>(kTriangleBytes)) {
      bad(where + " has impossible counts");
    }
    if (b.num_vertices == 0 && b.num_triangles > 0) bad(where + " has triangles but no vertices");
    if (!seen.insert({b.bx, b.by, b.bz}).second) bad(where + " appears twice");
    expected += static_cast<int64_t>(b.num_vertices) * kVertexBytes + static_cast<int64_t>(b.num_triangles) * kTriangleBytes;
  }
  if (expected != m.raw_size) {
    bad("the blocks' counts need " + std::to_string(expected) + " bytes but raw_size is " + std::to_string(m.raw_size));
  }
}

// Inflates into exactly raw_size bytes: never allocates more, so a zlib bomb costs nothing.
std::vector<uint8_t> inflateExactly(const rekon_msgs::mesh_blocks_t& m) {
  // One spare byte: a payload that inflates to more than raw_size fills it and is caught.
  std::vector<uint8_t> raw(static_cast<size_t>(m.raw_size) + 1);
  z_stream z{};
  if (inflateInit(&z) != Z_OK) throw Error("mesh_blocks_t: zlib cannot start");
  z.next_in = const_cast<Bytef*>(m.payload.data());
  z.avail_in = static_cast<uInt>(m.payload.size());
  z.next_out = raw.data();
  z.avail_out = static_cast<uInt>(raw.size());
  const int rc = inflate(&z, Z_FINISH);
  const uLong produced = z.total_out;
  inflateEnd(&z);
  raw.pop_back();
  if (rc != Z_STREAM_END || produced != raw.size()) {
    throw Error("mesh_blocks_t: the payload does not inflate to raw_size " + std::to_string(m.raw_size) +
                " bytes (corrupt or truncated); message dropped");
  }
  return raw;
}

}  // namespace

std::vector<BlockMesh> decodeMeshBlocks(const rekon_msgs::mesh_blocks_t& msg) {
  checkHeader(msg);
  const std::vector<uint8_t> raw = inflateExactly(msg);
  const double block_size = msg.block_voxels * msg.voxel_size;
  const uint8_t* p = raw.data();
  std::vector<BlockMesh> out;
  out.reserve(msg.blocks.size());
  for (const auto& h : msg.blocks) {
    BlockMesh b;
    b.x = h.bx;
    b.y = h.by;
    b.z = h.bz;
    b.version = h.version;
    b.cause = static_cast<BlockCause>(h.cause);
    const double corner[3] = {h.bx * block_size, h.by * block_size, h.bz * block_size};
    b.vertices.resize(h.num_vertices);
    for (auto& v : b.vertices) {
      for (int i = 0; i < 3; ++i, p += 2) v[i] = static_cast<float>(corner[i] + getU16(p) * msg.quantum);
    }
    b.colors.resize(h.num_vertices);
    for (auto& c : b.colors) {
      std::memcpy(c.data(), p, 3);
      p += 3;
    }
    b.triangles.resize(h.num_triangles);
    for (auto& t : b.triangles) {
      for (int i = 0; i < 3; ++i, p += 2) {
        t[i] = getU16(p);
        if (t[i] >= h.num_vertices) {
          throw Error("mesh_blocks_t: block " + coordText(h.bx, h.by, h.bz) + " has triangle index " + std::to_string(t[i]) +
                      " of " + std::to_string(h.num_vertices) + " vertices; message dropped");
        }
      }
    }
    out.push_back(std::move(b));
  }
  return out;
}

int MeshMap::apply(const std::vector<BlockMesh>& blocks) {
  int changed = 0;
  for (const BlockMesh& b : blocks) {
    const Key key{b.x, b.y, b.z};
    const auto it = blocks_.find(key);
    if (it != blocks_.end() && it->second.version > b.version) continue;
    ++changed;
    if (b.vertices.empty()) {
      if (it != blocks_.end()) blocks_.erase(it);
    } else {
      blocks_[key] = b;
    }
  }
  return changed;
}

int MeshMap::apply(const rekon_msgs::mesh_blocks_t& msg) {
  std::vector<BlockMesh> blocks = decodeMeshBlocks(msg);
  quantum_ = msg.quantum;
  if (msg.full && msg.part == 0) blocks_.clear();
  return apply(blocks);
}

size_t MeshMap::vertexCount() const {
  size_t n = 0;
  for (const auto& [key, b] : blocks_) n += b.vertices.size();
  return n;
}

size_t MeshMap::triangleCount() const {
  size_t n = 0;
  for (const auto& [key, b] : blocks_) n += b.triangles.size();
  return n;
}

const BlockMesh* MeshMap::find(int32_t x, int32_t y, int32_t z) const {
  const auto it = blocks_.find({x, y, z});
  return it == blocks_.end() ? nullptr : &it->second;
}

Mesh MeshMap::toMesh() const {
  struct KeyHash {
    size_t operator()(const std::array<int64_t, 3>& k) const {
      // Unsigned: wraps where a hostile block's coordinates are huge (signed would overflow).
      return static_cast<size_t>(static_cast<uint64_t>(k[0]) * 73856093ULL ^ static_cast<uint64_t>(k[1]) * 19349663ULL ^
                                 static_cast<uint64_t>(k[2]) * 83492791ULL);
    }
  };
  // Vertices are identified by their quanta (recovered from float metres,
  // exact while coordinates stay below ~100 m at 1 cm voxels).
  const double per_metre = quantum_ > 0.0 ? 1.0 / quantum_ : 0.0;
  std::unordered_map<std::array<int64_t, 3>, int, KeyHash> index;
  Mesh mesh;
  std::vector<int> local;
  for (const auto& [key, b] : blocks_) {
    local.resize(b.vertices.size());
    for (size_t i = 0; i < b.vertices.size(); ++i) {
      const Eigen::Vector3f& v = b.vertices[i];
      const std::array<int64_t, 3> k{std::llround(v.x() * per_metre), std::llround(v.y() * per_metre), std::llround(v.z() * per_metre)};
      const auto [it, fresh] = per_metre > 0.0 ? index.try_emplace(k, static_cast<int>(mesh.vertices.size()))
                                               : std::make_pair(index.end(), true);
      if (fresh) {
        mesh.vertices.push_back(v);
        mesh.colors.push_back(b.colors[i]);
      }
      local[i] = fresh ? static_cast<int>(mesh.vertices.size()) - 1 : it->second;
    }
    for (const Eigen::Vector3i& t : b.triangles) mesh.triangles.emplace_back(local[t[0]], local[t[1]], local[t[2]]);
  }
  return mesh;
}

}  // namespace rekon
