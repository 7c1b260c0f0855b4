#include <gtest/gtest.h>

#include <zlib.h>

#include <cmath>
#include <random>

#include "rekon/common/bus.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/mesh_blocks.hpp"

namespace {

constexpr double kVoxel = 0.01;
constexpr double kBlock = 8 * kVoxel;
constexpr double kQuantum = kVoxel / 1024;

rekon::MeshBlocksParams params(size_t max_bytes = rekon::MeshBlocksParams::kDefaultMaxMessageBytes) {
  rekon::MeshBlocksParams p;
  p.voxel_size = kVoxel;
  p.block_voxels = 8;
  p.max_message_bytes = max_bytes;
  return p;
}

// A block with n random vertices inside it (and up to one block beyond its +x/+y/+z faces, as
// vertices shared with a neighbour are) and n random triangles.
rekon::BlockMesh randomBlock(int x, int y, int z, int n, std::mt19937& rng) {
  rekon::BlockMesh b;
  b.x = x;
  b.y = y;
  b.z = z;
  b.version = 3;
  std::uniform_real_distribution<double> within(0.0, 1.9 * kBlock);
  std::uniform_int_distribution<int> byte(0, 255), index(0, n - 1);
  for (int i = 0; i < n; ++i) {
    b.vertices.emplace_back(static_cast<float>(x * kBlock + within(rng)), static_cast<float>(y * kBlock + within(rng)),
                            static_cast<float>(z * kBlock + within(rng)));
    b.colors.push_back({static_cast<uint8_t>(byte(rng)), static_cast<uint8_t>(byte(rng)), static_cast<uint8_t>(byte(rng))});
    b.triangles.emplace_back(index(rng), index(rng), index(rng));
  }
  return b;
}

rekon_msgs::mesh_blocks_t oneMessage(const std::vector<rekon::BlockMesh>& blocks) {
  auto msgs = rekon::encodeMeshBlocks(blocks, params(), 1, false);
  EXPECT_EQ(msgs.size(), 1u);
  return msgs.front();
}

void recompress(rekon_msgs::mesh_blocks_t& m, const std::vector<uint8_t>& raw) {
  uLongf size = compressBound(static_cast<uLong>(raw.size()));
  m.payload.resize(size);
  compress2(m.payload.data(), &size, raw.data(), static_cast<uLong>(raw.size()), 1);
  m.payload.resize(size);
  m.payload_size = static_cast<int32_t>(size);
  m.raw_size = static_cast<int32_t>(raw.size());
}

std::vector<uint8_t> inflated(const rekon_msgs::mesh_blocks_t& m) {
  std::vector<uint8_t> raw(static_cast<size_t>(m.raw_size));
  uLongf size = raw.size();
  uncompress(raw.data(), &size, m.payload.data(), static_cast<uLong>(m.payload.size()));
  return raw;
}

}  // namespace

TEST(MeshBlocks, RoundTripKeepsVerticesWithinHalfAQuantumAndColorsAndTrianglesExactly) {
  std::mt19937 rng(7);
  const std::vector<rekon::BlockMesh> blocks = {randomBlock(0, 0, 0, 200, rng), randomBlock(-3, 5, -120, 50, rng)};
  const auto decoded = rekon::decodeMeshBlocks(oneMessage(blocks));
  ASSERT_EQ(decoded.size(), 2u);
  for (size_t b = 0; b < 2; ++b) {
    EXPECT_EQ(decoded[b].x, blocks[b].x);
    EXPECT_EQ(decoded[b].z, blocks[b].z);
    EXPECT_EQ(decoded[b].version, 3);
    ASSERT_EQ(decoded[b].vertices.size(), blocks[b].vertices.size());
    EXPECT_EQ(decoded[b].colors, blocks[b].colors);
    EXPECT_EQ(decoded[b].triangles, blocks[b].triangles);
    for (size_t i = 0; i < blocks[b].vertices.size(); ++i) {
      // Half a quantum from rounding, plus float rounding of metres near 10 m (1 um).
      EXPECT_LE((decoded[b].vertices[i] - blocks[b].vertices[i]).cwiseAbs().maxCoeff(), kQuantum / 2 + 1e-6);
    }
  }
}

TEST(MeshBlocks, AVertexSharedByTwoBlocksGetsTheSameQuanta) {
  rekon::BlockMesh a, b;
  a.x = 0;
  b.x = 1;
  const Eigen::Vector3f shared(static_cast<float>(kBlock + 0.37 * kVoxel), 0.0123f, 0.0456f);
  a.vertices = b.vertices = {shared};
  a.colors = b.colors = {{1, 2, 3}};
  rekon::MeshMap map;
  map.apply(oneMessage({a, b}));
  EXPECT_EQ(map.vertexCount(), 2u);
  EXPECT_EQ(map.toMesh().vertices.size(), 1u);  // merged, as the mapper's mesh shares it
}

TEST(MeshBlocks, LargeUpdatesAreSplitIntoPartsThatFitAndShareTheSequence) {
  std::mt19937 rng(1);
  std::vector<rekon::BlockMesh> blocks;
  for (int i = 0; i < 40; ++i) blocks.push_back(randomBlock(i, 0, 0, 1000, rng));  // ~15 KB raw each, random: incompressible
  const size_t limit = 64 * 1024;
  auto msgs = rekon::encodeMeshBlocks(blocks, params(limit), 42, true);
  ASSERT_GE(msgs.size(), 8u);  // 600 KB of barely compressible bytes in 64 KB messages
  size_t total_blocks = 0;
  for (size_t i = 0; i < msgs.size(); ++i) {
    EXPECT_LE(static_cast<size_t>(msgs[i].getEncodedSize()), limit);
    EXPECT_EQ(msgs[i].sequence, 42);
    EXPECT_EQ(msgs[i].part, static_cast<int32_t>(i));
    EXPECT_EQ(msgs[i].parts, static_cast<int32_t>(msgs.size()));
    EXPECT_TRUE(msgs[i].full);
    total_blocks += rekon::decodeMeshBlocks(msgs[i]).size();
  }
  EXPECT_EQ(total_blocks, 40u);
}

// The run's last update is encoded on every core: the same blocks in the
// same order, parts numbered across the threads' slices, and an error in a
// helper thread's slice thrown to the caller.
TEST(MeshBlocks, EncodingOnSeveralThreadsKeepsTheBlocksAndTheirOrder) {
  std::mt19937 rng(2);
  std::vector<rekon::BlockMesh> blocks;
  for (int i = 0; i < 2500; ++i) blocks.push_back(randomBlock(i, -i, 7, 20, rng));
  const size_t limit = 16 * 1024;
  auto decodeAll = [](const std::vector<rekon_msgs::mesh_blocks_t>& msgs) {
    std::vector<rekon::BlockMesh> out;
    for (const auto& m : msgs)
      for (auto& b : rekon::decodeMeshBlocks(m)) out.push_back(std::move(b));
    return out;
  };
  const auto alone = rekon::encodeMeshBlocks(blocks, params(limit), 5, false, 1);
  const auto shared = rekon::encodeMeshBlocks(blocks, params(limit), 5, false, 2);
  for (size_t i = 0; i < shared.size(); ++i) {
    EXPECT_LE(static_cast<size_t>(shared[i].getEncodedSize()), limit);
    EXPECT_EQ(shared[i].part, static_cast<int32_t>(i));
    EXPECT_EQ(shared[i].parts, static_cast<int32_t>(shared.size()));
  }
  const auto a = decodeAll(alone), b = decodeAll(shared);
  ASSERT_EQ(a.size(), blocks.size());
  ASSERT_EQ(b.size(), blocks.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(std::tie(a[i].x, a[i].y, a[i].z), std::tie(b[i].x, b[i].y, b[i].z)) << i;
    EXPECT_EQ(a[i].vertices, b[i].vertices) << i;
    EXPECT_EQ(a[i].triangles, b[i].triangles) << i;
  }
  blocks.push_back(randomBlock(0, 0, 0, 3000, rng));  // in the second thread's slice, too big for a message
  EXPECT_THROW(rekon::encodeMeshBlocks(blocks, params(limit), 6, false, 2), rekon::Error);
}

TEST(MeshBlocks, ABlockTooBigForOneMessageIsAClearError) {
  std::mt19937 rng(2);
  EXPECT_THROW(rekon::encodeMeshBlocks({randomBlock(0, 0, 0, 3000, rng)}, params(4096), 1, false), rekon::Error);
}

TEST(MeshBlocks, MoreThan65535VerticesInABlockIsAClearError) {
  rekon::BlockMesh b;
  b.vertices.assign(65536, Eigen::Vector3f::Zero());
  b.colors.assign(65536, {0, 0, 0});
  try {
    rekon::encodeMeshBlocks({b}, params(), 1, false);
    FAIL() << "encoded 65536 vertices";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("65535"), std::string::npos) << e.what();
  }
}

TEST(MeshBlocks, AnEmptyBlockRemovesItAndAnOlderVersionIsIgnored) {
  std::mt19937 rng(3);
  rekon::MeshMap map;
  auto b = randomBlock(1, 2, 3, 10, rng);
  b.version = 5;
  EXPECT_EQ(map.apply({b}), 1);
  auto older = b;
  older.version = 4;
  older.vertices.resize(3);
  EXPECT_EQ(map.apply({older}), 0);
  EXPECT_EQ(map.find(1, 2, 3)->vertices.size(), 10u);
  rekon::BlockMesh removed;
  removed.x = 1;
  removed.y = 2;
  removed.z = 3;
  removed.version = 6;
  EXPECT_EQ(map.apply(oneMessage({removed})), 1);
  EXPECT_EQ(map.blockCount(), 0u);
}

TEST(MeshBlocksHostile, CountsThatDisagreeWithThePayloadAreRejected) {
  std::mt19937 rng(4);
  auto m = oneMessage({randomBlock(0, 0, 0, 10, rng)});
  m.blocks[0].num_vertices = 11;
  EXPECT_THROW(rekon::decodeMeshBlocks(m), rekon::Error);
  m.blocks[0].num_vertices = -1;
  EXPECT_THROW(rekon::decodeMeshBlocks(m), rekon::Error);
  m.blocks[0].num_vertices = 10;
  m.num_blocks = 2;
  EXPECT_THROW(rekon::decodeMeshBlocks(m), rekon::Error);
}

TEST(MeshBlocksHostile, APayloadThatDoesNotInflateToRawSizeIsRejected) {
  std::mt19937 rng(5);
  auto m = oneMessage({randomBlock(0, 0, 0, 10, rng)});
  auto truncated = m;
  truncated.payload.resize(m.payload.size() / 2);
  truncated.payload_size = static_cast<int32_t>(truncated.payload.size());
  EXPECT_THROW(rekon::decodeMeshBlocks(truncated), rekon::Error);
  auto garbage = m;
  for (auto& byte : garbage.payload) byte ^= 0x5a;
  EXPECT_THROW(rekon::decodeMeshBlocks(garbage), rekon::Error);
  auto longer = m;  // inflates to more than raw_size (counts adjusted to match the smaller raw_size)
  auto raw = inflated(m);
  raw.resize(raw.size() + 9);
  recompress(longer, raw);
  longer.raw_size -= 9;
  EXPECT_THROW(rekon::decodeMeshBlocks(longer), rekon::Error);
}

TEST(MeshBlocksHostile, AZlibBombIsRejectedBeforeInflating) {
  rekon_msgs::mesh_blocks_t m{};
  m.voxel_size = kVoxel;
  m.block_voxels = 8;
  m.quantum = kQuantum;
  m.parts = 1;
  m.num_blocks = 1;
  m.blocks = {{0, 0, 0, 1, 65535, 20000000, 0}};  // 120 MB of triangles, consistent with raw_size
  recompress(m, std::vector<uint8_t>(1000, 0));
  m.raw_size = 65535 * 9 + 20000000 * 6;
  EXPECT_THROW(rekon::decodeMeshBlocks(m), rekon::Error);
}

TEST(MeshBlocksHostile, TriangleIndicesOutOfRangeAreRejected) {
  std::mt19937 rng(6);
  auto m = oneMessage({randomBlock(0, 0, 0, 10, rng)});
  auto raw = inflated(m);
  raw[10 * 9] = 10;  // the first index: vertex 10 of 10
  raw[10 * 9 + 1] = 0;
  recompress(m, raw);
  EXPECT_THROW(rekon::decodeMeshBlocks(m), rekon::Error);
}

TEST(MeshBlocksHostile, AbsurdHeaderValuesAreRejected) {
  std::mt19937 rng(7);
  const auto good = oneMessage({randomBlock(0, 0, 0, 10, rng)});
  EXPECT_NO_THROW(rekon::decodeMeshBlocks(good));
  std::vector<void (*)(rekon_msgs::mesh_blocks_t&)> breakers = {
      [](rekon_msgs::mesh_blocks_t& m) { m.voxel_size = std::nan(""); },
      [](rekon_msgs::mesh_blocks_t& m) { m.voxel_size = -0.01; },
      [](rekon_msgs::mesh_blocks_t& m) { m.quantum = INFINITY; },
      [](rekon_msgs::mesh_blocks_t& m) { m.quantum = 0.0; },
      [](rekon_msgs::mesh_blocks_t& m) { m.block_voxels = 0; },
      [](rekon_msgs::mesh_blocks_t& m) { m.block_voxels = 1 << 30; },
      [](rekon_msgs::mesh_blocks_t& m) { m.parts = 0; },
      [](rekon_msgs::mesh_blocks_t& m) { m.part = 1; },
      [](rekon_msgs::mesh_blocks_t& m) { m.raw_size = -1; },
      [](rekon_msgs::mesh_blocks_t& m) { m.blocks[0].bx = 1 << 30; },
      [](rekon_msgs::mesh_blocks_t& m) { m.blocks[0].version = -2; },
      [](rekon_msgs::mesh_blocks_t& m) {
        m.blocks.push_back(m.blocks[0]);  // listed twice, empty the second time
        m.blocks[1].num_vertices = m.blocks[1].num_triangles = 0;
        m.num_blocks = 2;
      },
  };
  for (size_t i = 0; i < breakers.size(); ++i) {
    auto m = good;
    breakers[i](m);
    EXPECT_THROW(rekon::decodeMeshBlocks(m), rekon::Error) << "breaker " << i;
  }
}

TEST(MeshBlocksHostile, AHostileMessageOnTheBusIsDroppedByTheLcmDecoderOrByTheMeshDecoder) {
  std::mt19937 rng(8);
  auto m = oneMessage({randomBlock(0, 0, 0, 10, rng)});
  m.schema_version = rekon::kSchemaVersion;
  std::string buf(static_cast<size_t>(m.getEncodedSize()), '\0');
  m.encode(buf.data(), 0, static_cast<int>(buf.size()));
  std::mt19937 flip(9);
  int rejected = 0;
  for (int trial = 0; trial < 500; ++trial) {
    std::string b = buf;
    for (int k = 0; k < 4; ++k) b[flip() % b.size()] ^= static_cast<char>(1 + flip() % 255);
    rekon_msgs::mesh_blocks_t d;
    std::string why;
    if (!rekon::decodeMessage(b.data(), static_cast<int>(b.size()), &d, &why)) {
      ++rejected;
      continue;
    }
    try {
      rekon::decodeMeshBlocks(d);
    } catch (const rekon::Error&) {
      ++rejected;
    }
  }
  // Four flipped bytes mostly hit the compressed payload (its adler32 catches them) or a header field.
  EXPECT_GT(rejected, 250);
}
