// The volume's per-block meshes (issue 17, the map on the bus): each block's
// mesh holds exactly extractMesh()'s vertices, takeMeshChanges() names every
// block whose mesh changed, and the blocks sent through the codec assemble
// into extractMesh()'s surface.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <tuple>

#include "analytic_scene.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"

namespace {

using rekon::BlockMesh;
using rekon::volume::BlockCoord;
using rekon::volume::TsdfVolume;
using rekon::volume::VolumeParams;

using Point = std::tuple<float, float, float>;
using Key = std::tuple<int, int, int>;

Point pointOf(const Eigen::Vector3f& v) { return {v.x(), v.y(), v.z()}; }

// A triangle as its three corners, rotated so the smallest comes first (orientation kept).
std::tuple<Point, Point, Point> triangleOf(const std::vector<Eigen::Vector3f>& v, const Eigen::Vector3i& t) {
  Point p[3] = {pointOf(v[t[0]]), pointOf(v[t[1]]), pointOf(v[t[2]])};
  const int first = static_cast<int>(std::min_element(p, p + 3) - p);
  return {p[first], p[(first + 1) % 3], p[(first + 2) % 3]};
}

std::map<Key, BlockMesh> byCoord(const std::vector<BlockMesh>& meshes) {
  std::map<Key, BlockMesh> out;
  for (const BlockMesh& m : meshes) out[{m.x, m.y, m.z}] = m;
  return out;
}

bool sameMesh(const BlockMesh& a, const BlockMesh& b) {
  return a.vertices == b.vertices && a.colors == b.colors && a.triangles == b.triangles;
}

class VolumeMeshBlocks : public ::testing::Test {
 protected:
  VolumeParams params() const {
    VolumeParams p;
    p.backend = "cpu";
    p.block_capacity = 1024;
    return p;
  }
  void integrate(TsdfVolume& vol, double degrees) const {
    cv::Mat depth, color;
    const rekon::Pose pose = rekon::test::orbitPose(scene_, degrees);
    rekon::test::renderSphereScene(scene_, k_, pose, depth, color);
    vol.integrate(depth, color, cv::Mat(), k_, pose);
  }
  void deintegrate(TsdfVolume& vol, double degrees) const {
    cv::Mat depth, color;
    const rekon::Pose pose = rekon::test::orbitPose(scene_, degrees);
    rekon::test::renderSphereScene(scene_, k_, pose, depth, color);
    vol.deintegrate(depth, color, cv::Mat(), k_, pose);
  }
  std::map<Key, BlockMesh> allBlockMeshes(const TsdfVolume& vol) const { return byCoord(vol.meshBlocks(vol.blockCoords())); }

  rekon::test::SphereScene scene_;
  rekon::Intrinsics k_ = rekon::test::smallCamera();
};

}  // namespace

TEST_F(VolumeMeshBlocks, BlockMeshesHoldExactlyTheVerticesAndTrianglesOfExtractMesh) {
  TsdfVolume vol(params());
  integrate(vol, 0);
  integrate(vol, 25);
  const rekon::Mesh whole = vol.extractMesh();
  ASSERT_GT(whole.triangles.size(), 1000u);
  std::set<Point> whole_points, block_points;
  for (const auto& v : whole.vertices) whole_points.insert(pointOf(v));
  std::multiset<std::tuple<Point, Point, Point>> whole_triangles, block_triangles;
  for (const auto& t : whole.triangles) whole_triangles.insert(triangleOf(whole.vertices, t));
  for (const auto& [key, b] : allBlockMeshes(vol)) {
    for (const auto& v : b.vertices) block_points.insert(pointOf(v));
    for (const auto& t : b.triangles) block_triangles.insert(triangleOf(b.vertices, t));
  }
  EXPECT_EQ(block_points, whole_points);  // bit for bit
  EXPECT_EQ(block_triangles, whole_triangles);
}

// The run's last update meshes on every worker: block for block the same
// meshes, in the same order, as the calling thread alone makes them.
TEST_F(VolumeMeshBlocks, MeshingOnEveryWorkerGivesTheSameMeshes) {
  TsdfVolume vol(params());
  integrate(vol, 0);
  integrate(vol, 25);
  const std::vector<BlockMesh> alone = vol.meshBlocks(vol.blockCoords(), 1);
  const std::vector<BlockMesh> all = vol.meshBlocks(vol.blockCoords(), 0);
  ASSERT_GT(alone.size(), 100u);
  ASSERT_EQ(all.size(), alone.size());
  for (size_t i = 0; i < all.size(); ++i) {
    EXPECT_TRUE(std::tie(all[i].x, all[i].y, all[i].z) == std::tie(alone[i].x, alone[i].y, alone[i].z)) << i;
    EXPECT_TRUE(sameMesh(all[i], alone[i])) << i;
  }
}

TEST_F(VolumeMeshBlocks, MeshChangesNameEveryBlockWhoseMeshChangedAfterIntegration) {
  TsdfVolume vol(params());
  integrate(vol, 0);
  vol.takeMeshChanges();
  const auto before = allBlockMeshes(vol);
  integrate(vol, 30);
  const auto changes = vol.takeMeshChanges();
  std::set<Key> named;
  for (const BlockCoord& c : changes) named.insert({c.x, c.y, c.z});
  const auto after = allBlockMeshes(vol);
  int changed = 0;
  for (const auto& [key, mesh] : after) {
    const auto old = before.find(key);
    if (old != before.end() && sameMesh(old->second, mesh)) continue;
    ++changed;
    EXPECT_TRUE(named.count(key)) << "block " << std::get<0>(key) << " " << std::get<1>(key) << " " << std::get<2>(key);
  }
  EXPECT_GT(changed, 50);  // a second view 30 degrees on changes much of the sphere and the wall
  EXPECT_TRUE(vol.takeMeshChanges().empty());  // nothing since
}

TEST_F(VolumeMeshBlocks, DeintegrationNamesTheFreedBlocksAndTheirMeshIsEmpty) {
  TsdfVolume vol(params());
  integrate(vol, 0);
  const auto first = vol.blockCoords();
  integrate(vol, 60);
  vol.takeMeshChanges();
  deintegrate(vol, 60);
  const auto changes = vol.takeMeshChanges();
  std::set<Key> named, still;
  for (const BlockCoord& c : changes) named.insert({c.x, c.y, c.z});
  for (const BlockCoord& c : vol.blockCoords()) still.insert({c.x, c.y, c.z});
  ASSERT_EQ(still.size(), first.size());  // exactly the first view's blocks remain
  std::vector<BlockCoord> freed;
  for (const Key& k : named) {
    if (!still.count(k)) freed.push_back({std::get<0>(k), std::get<1>(k), std::get<2>(k)});
  }
  ASSERT_GT(freed.size(), 10u);
  for (const BlockMesh& m : vol.meshBlocks(freed)) EXPECT_TRUE(m.vertices.empty() && m.triangles.empty());
}

TEST_F(VolumeMeshBlocks, StreamingChangesNoMesh) {
  VolumeParams p = params();
  p.streaming_radius = 0.5;
  TsdfVolume vol(p);
  integrate(vol, 0);
  vol.takeMeshChanges();
  const auto before = allBlockMeshes(vol);
  vol.streamAround(Eigen::Vector3d(50, 0, 0));  // everything to the host store
  ASSERT_EQ(vol.stats().active_blocks, 0);
  EXPECT_TRUE(vol.takeMeshChanges().empty());
  const auto after = allBlockMeshes(vol);
  ASSERT_EQ(after.size(), before.size());
  for (const auto& [key, mesh] : after) EXPECT_TRUE(sameMesh(mesh, before.at(key)));
}

TEST_F(VolumeMeshBlocks, BlocksSentThroughTheCodecAssembleIntoExtractMeshsSurface) {
  TsdfVolume vol(params());
  integrate(vol, 0);
  integrate(vol, 40);
  const rekon::Mesh whole = vol.extractMesh();
  rekon::MeshBlocksParams codec;
  codec.voxel_size = params().voxel_size;
  codec.max_message_bytes = 32 * 1024;  // several parts
  rekon::MeshMap map;
  const auto msgs = rekon::encodeMeshBlocks(vol.meshBlocks(vol.blockCoords()), codec, 1, true);
  ASSERT_GT(msgs.size(), 1u);
  for (const auto& m : msgs) map.apply(m);
  const rekon::Mesh assembled = map.toMesh();
  // Vertices compared by their quanta: the mapper's coincident vertices (a
  // zero-distance voxel puts several at one point) count once on both sides.
  const double per_metre = 1.0 / codec.quantum();
  auto quanta = [&](const std::vector<Eigen::Vector3f>& vs) {
    std::set<std::tuple<long long, long long, long long>> out;
    for (const auto& v : vs) out.insert({std::llround(v.x() * per_metre), std::llround(v.y() * per_metre), std::llround(v.z() * per_metre)});
    return out;
  };
  EXPECT_EQ(quanta(assembled.vertices), quanta(whole.vertices));
  EXPECT_EQ(assembled.vertices.size(), quanta(whole.vertices).size());
  EXPECT_EQ(assembled.triangles.size(), whole.triangles.size());
}
