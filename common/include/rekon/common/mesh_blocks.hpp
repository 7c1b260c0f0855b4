#pragma once
// The mapper's surface on the bus (messages/mesh.lcm, channel MESH_BLOCKS):
// per-block meshes to and from mesh_blocks_t, and MeshMap, which keeps the
// newest version of every block and assembles the whole mesh. Positions travel
// as uint16 quanta from the block's lower corner (quantum = voxel_size / 1024
// by default), colors as RGB, indices as uint16 within the block, all zlib
// compressed in one payload per message.
#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <tuple>
#include <vector>

#include "rekon/common/mesh.hpp"
#include "rekon_msgs/mesh_blocks_t.hpp"

namespace rekon {

// Why a block's mesh changed (mesh_block_t.cause): a viewer counts and
// highlights corrections, not every re-sent block.
enum class BlockCause : int8_t {
  kNewData = 0,     // keyframe fusion integrated new data
  kCorrection = 1,  // a graph update's re-integration changed it
  kFinalPass = 2,   // the final pass re-integrated it at the end of the stream
};
inline constexpr int8_t kMaxBlockCause = 2;

struct BlockMesh {
  int32_t x = 0, y = 0, z = 0;  // block coordinates (lower corner = coords * block_voxels * voxel_size)
  int64_t version = 0;
  std::vector<Eigen::Vector3f> vertices;  // world metres; empty: the block was removed
  std::vector<std::array<uint8_t, 3>> colors;  // RGB, one per vertex
  std::vector<Eigen::Vector3i> triangles;  // indices into this block's vertices
  BlockCause cause = BlockCause::kNewData;
};

struct MeshBlocksParams {
  static constexpr int kDefaultQuantaPerVoxel = 1024;  // 10 um steps at 1 cm voxels
  static constexpr size_t kDefaultMaxMessageBytes = 256 * 1024;
  static constexpr int kDefaultZlibLevel = 1;  // fastest: the mapper's CPU matters more than a few % of bytes

  double voxel_size = 0.01;
  int block_voxels = 8;
  int quanta_per_voxel = kDefaultQuantaPerVoxel;
  size_t max_message_bytes = kDefaultMaxMessageBytes;  // encoded LCM size of each message
  int zlib_level = kDefaultZlibLevel;
  double quantum() const { return voxel_size / quanta_per_voxel; }
};

// Limits the decoder enforces on anything that arrives from outside.
inline constexpr int32_t kMaxMeshRawBytes = 64 << 20;  // inflated payload of one message (zlib bombs)
inline constexpr int32_t kMaxMeshBlockCoord = 1 << 20;  // |block coordinate|: kilometres of map
inline constexpr int32_t kMaxMeshParts = 1 << 16;

// One update (every part shares `sequence`), split into messages of at most
// params.max_message_bytes each. Vertices are quantised against the global
// lattice of quanta, so a vertex shared by two blocks gets the same quanta in
// both. Throws rekon::Error for a block with more than 65535 vertices, one
// that does not fit a message on its own, or vertices outside the 16-bit
// range of their block (more than 65535 quanta from its lower corner).
// Compressed on up to `threads` threads (1: the calling thread only; at
// least 1000 blocks a thread): the blocks in the same order either way, only
// the cuts between parts may differ.
std::vector<rekon_msgs::mesh_blocks_t> encodeMeshBlocks(const std::vector<BlockMesh>& blocks,
                                                        const MeshBlocksParams& params, int64_t sequence, bool full,
                                                        int threads = 1);

// Every block of one message, vertices in world metres. Throws rekon::Error
// (one line) for hostile or inconsistent input: absurd header values, counts
// that disagree with the payload, a payload that does not inflate to exactly
// raw_size, raw_size above kMaxMeshRawBytes, indices out of range.
std::vector<BlockMesh> decodeMeshBlocks(const rekon_msgs::mesh_blocks_t& msg);

// The newest version of every block, as a subscriber keeps it.
class MeshMap {
 public:
  // Keeps each block unless a newer version is already held; an empty block
  // removes it. Returns how many blocks changed.
  int apply(const std::vector<BlockMesh>& blocks);
  // Decodes (throws as decodeMeshBlocks) and applies; the first part of a
  // full snapshot first forgets every block (those it lacks are gone).
  int apply(const rekon_msgs::mesh_blocks_t& msg);
  void clear() { blocks_.clear(); }

  size_t blockCount() const { return blocks_.size(); }
  size_t vertexCount() const;
  size_t triangleCount() const;
  const BlockMesh* find(int32_t x, int32_t y, int32_t z) const;

  // All blocks in one mesh. Vertices two blocks share (along their common
  // faces) are merged when their quanta agree, so the mesh is as connected
  // as the mapper's; coincident vertices within a block are merged alike.
  Mesh toMesh() const;

 private:
  using Key = std::tuple<int32_t, int32_t, int32_t>;
  std::map<Key, BlockMesh> blocks_;
  double quantum_ = 0.0;  // of the last message; 0 before any
};

}  // namespace rekon
