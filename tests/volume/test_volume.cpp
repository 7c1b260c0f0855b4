// Specification of the TSDF volume (issue 6). Every test runs on every
// backend available in this process (CPU always, CUDA with a device).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <tuple>

#include "analytic_scene.hpp"
#include "rekon/common/error.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"
#include "rekon/mapper/volume/volume_config.hpp"
#include "test_support.hpp"
#include "volume_snapshot.hpp"

namespace {

using rekon::Pose;
using rekon::volume::BlockCoord;
using rekon::volume::TsdfVolume;
using rekon::volume::VolumeParams;
using rekon::volume::Voxel;

struct View {
  cv::Mat depth, color;
  Pose pose;
};

using rekon::test::Snapshot;
using rekon::test::snapshot;

struct Difference {
  int64_t sdf = 0, weight = 0, color = 0;  // color in 1/kColorScale levels
  bool same_blocks = true;
};

Difference compare(const Snapshot& a, const Snapshot& b) {
  Difference d;
  d.same_blocks = a.size() == b.size();
  for (const auto& [coord, va] : a) {
    auto it = b.find(coord);
    if (it == b.end()) {
      d.same_blocks = false;
      continue;
    }
    for (size_t i = 0; i < va.size(); ++i) {
      const Voxel &x = va[i], &y = it->second[i];
      d.sdf = std::max<int64_t>(d.sdf, std::abs(static_cast<int64_t>(x.sdf_sum) - y.sdf_sum));
      d.weight = std::max<int64_t>(
          d.weight, std::abs(static_cast<int64_t>(rekon::volume::voxelWeight(x)) - rekon::volume::voxelWeight(y)));
      for (int c = 0; c < 3; ++c) {
        d.color = std::max<int64_t>(d.color, std::abs(static_cast<int64_t>(rekon::volume::voxelColorFixed(x, c)) -
                                                      rekon::volume::voxelColorFixed(y, c)));
      }
    }
  }
  return d;
}

// The same blocks with the same voxels, bit for bit (streaming and spilling move voxels, never change them).
void expectSameVoxels(const Snapshot& a, const Snapshot& b) {
  const Difference d = compare(a, b);
  EXPECT_TRUE(d.same_blocks);
  EXPECT_EQ(d.sdf + d.weight + d.color, 0);
}

class VolumeTest : public ::testing::TestWithParam<std::string> {
 protected:
  VolumeParams params() const {
    VolumeParams p;
    p.backend = GetParam();
    p.block_capacity = 1024;
    return p;
  }
  View sphereView(double degrees) const {
    View v;
    v.pose = rekon::test::orbitPose(scene_, degrees);
    rekon::test::renderSphereScene(scene_, k_, v.pose, v.depth, v.color);
    return v;
  }
  void integrate(TsdfVolume& vol, const View& v) const { vol.integrate(v.depth, v.color, cv::Mat(), k_, v.pose); }
  void deintegrate(TsdfVolume& vol, const View& v) const { vol.deintegrate(v.depth, v.color, cv::Mat(), k_, v.pose); }

  rekon::test::SphereScene scene_;
  rekon::Intrinsics k_ = rekon::test::smallCamera();
};

TEST_P(VolumeTest, DeintegratingEveryFrameInAnotherOrderLeavesAnEmptyVolume) {
  TsdfVolume vol(params());
  const std::vector<double> angles{-40, -15, 10, 35};
  for (double a : angles) integrate(vol, sphereView(a));
  ASSERT_GT(vol.stats().blocks, 50);
  for (double a : {10.0, -40.0, 35.0, -15.0}) deintegrate(vol, sphereView(a));
  EXPECT_EQ(vol.stats().blocks, 0);  // every block lost all its weight and was freed
  EXPECT_EQ(vol.stats().active_blocks, 0);
}

TEST_P(VolumeTest, IntegratingAAndBThenDeintegratingBEqualsIntegratingA) {
  TsdfVolume ab(params()), a_only(params());
  const View a = sphereView(-20), b = sphereView(25);
  integrate(ab, a);
  integrate(ab, b);
  deintegrate(ab, b);
  integrate(a_only, a);
  const Difference d = compare(snapshot(ab), snapshot(a_only));
  EXPECT_TRUE(d.same_blocks);
  EXPECT_EQ(d.sdf, 0);     // weighted sums of integers: exact
  EXPECT_EQ(d.weight, 0);  // likewise
  // Color is an average (eq. 2 with rounding): within a quarter of an 8-bit level.
  EXPECT_LE(d.color, static_cast<int64_t>(rekon::volume::kColorScale / 4));
}

TEST_P(VolumeTest, APixelWeightOfTwoEqualsIntegratingTheFrameTwice) {
  TsdfVolume weighted(params()), twice(params());
  const View v = sphereView(0);
  weighted.integrate(v.depth, v.color, cv::Mat(v.depth.size(), CV_32FC1, cv::Scalar(2.0f)), k_, v.pose);
  integrate(twice, v);
  integrate(twice, v);
  const Difference d = compare(snapshot(weighted), snapshot(twice));
  EXPECT_TRUE(d.same_blocks);
  EXPECT_EQ(d.sdf, 0);
  EXPECT_EQ(d.weight, 0);
  EXPECT_EQ(d.color, 0);  // the same observation twice averages to itself
}

TEST_P(VolumeTest, StreamingOutAndBackInReturnsIdenticalVoxels) {
  VolumeParams p = params();
  p.streaming_radius = 3.0;
  TsdfVolume vol(p);
  integrate(vol, sphereView(-20));
  integrate(vol, sphereView(20));
  const Snapshot before = snapshot(vol);
  const int64_t blocks = vol.stats().blocks;
  vol.streamAround(Eigen::Vector3d(100, 0, 0));  // far away: everything leaves the active volume
  EXPECT_EQ(vol.stats().active_blocks, 0);
  EXPECT_EQ(vol.stats().streamed_out, blocks);
  vol.streamAround(scene_.centre);  // the views reach at most 1.5 m from the sphere centre
  EXPECT_EQ(vol.stats().active_blocks, blocks);
  EXPECT_EQ(vol.stats().streamed_in, blocks);
  expectSameVoxels(before, snapshot(vol));
}

TEST_P(VolumeTest, DeintegrationBringsStreamedOutBlocksBackAndEmptiesThem) {
  VolumeParams p = params();
  p.streaming_radius = 1.0;
  TsdfVolume vol(p);
  const View v = sphereView(0);
  integrate(vol, v);
  vol.streamAround(Eigen::Vector3d(100, 0, 0));
  ASSERT_EQ(vol.stats().active_blocks, 0);
  deintegrate(vol, v);
  EXPECT_EQ(vol.stats().blocks, 0);
  EXPECT_GT(vol.stats().streamed_in, 0);
}

TEST_P(VolumeTest, RunningOutOfBlocksWithoutGrowingNamesTheCapacityToRaise) {
  VolumeParams p = params();
  p.block_capacity = 16;  // far fewer than one view needs
  p.grow_capacity = false;
  TsdfVolume vol(p);
  try {
    integrate(vol, sphereView(0));
    FAIL() << "integration into a full pool must throw";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("raise block_capacity to at least"), std::string::npos) << e.what();
  }
}

TEST_P(VolumeTest, AGrowingPoolKeepsEveryBlock) {
  VolumeParams small = params(), large = params();
  small.block_capacity = 16;
  large.block_capacity = 1 << 14;
  TsdfVolume grown(small), roomy(large);
  for (double a : {-30.0, 0.0, 30.0}) {
    integrate(grown, sphereView(a));
    integrate(roomy, sphereView(a));
  }
  EXPECT_GT(grown.stats().block_capacity, 16);
  const Difference d = compare(snapshot(grown), snapshot(roomy));
  EXPECT_TRUE(d.same_blocks);
  EXPECT_EQ(d.sdf + d.weight + d.color, 0);
}

TEST_P(VolumeTest, MeshOfASphereHasItsRadiusAndOutwardNormals) {
  TsdfVolume vol(params());
  for (double a = -60; a <= 60; a += 20) integrate(vol, sphereView(a));
  const rekon::Mesh mesh = vol.extractMesh();
  ASSERT_GT(mesh.triangles.size(), 500u);
  ASSERT_EQ(mesh.colors.size(), mesh.vertices.size());
  double sum = 0;
  int n = 0, outward = 0, on_sphere = 0;
  for (const auto& v : mesh.vertices) {
    const double r = (v.cast<double>() - scene_.centre).norm();
    if (r < scene_.radius + 0.05) {  // the sphere, not the wall
      sum += r;
      ++n;
    }
  }
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3f a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], c = mesh.vertices[t[2]];
    const Eigen::Vector3d centroid = ((a + b + c) / 3.f).cast<double>();
    if ((centroid - scene_.centre).norm() > scene_.radius + 0.05) continue;
    const Eigen::Vector3d normal = (b - a).cross(c - a).cast<double>();
    if (normal.norm() < 1e-9) continue;  // degenerate: a vertex on a voxel
    ++on_sphere;
    outward += normal.dot(centroid - scene_.centre) > 0;
  }
  ASSERT_GT(n, 200);
  EXPECT_NEAR(sum / n, scene_.radius, 0.002);  // within 2 mm at 1 cm voxels
  EXPECT_EQ(outward, on_sphere);               // normals point to free space
}

TEST_P(VolumeTest, ASphereSeenFromAllSidesGivesAClosedMesh) {
  rekon::test::SphereScene free_sphere = scene_;
  free_sphere.wall_z = 1e6;  // no wall: beyond max_depth
  TsdfVolume vol(params());
  for (int dx = -1; dx <= 1; ++dx) {
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dz = -1; dz <= 1; ++dz) {
        if (dx == 0 && dy == 0 && dz == 0) continue;
        const Eigen::Vector3d eye = free_sphere.centre + 0.9 * Eigen::Vector3d(dx, dy, dz).normalized();
        View v;
        v.pose = rekon::test::lookAt(eye, free_sphere.centre);
        rekon::test::renderSphereScene(free_sphere, k_, v.pose, v.depth, v.color);
        integrate(vol, v);
      }
    }
  }
  const rekon::Mesh mesh = vol.extractMesh();
  ASSERT_GT(mesh.triangles.size(), 5000u);
  // Closed and consistently oriented: every directed edge appears once and its reverse once.
  std::map<std::pair<int, int>, int> directed;
  for (const auto& t : mesh.triangles) {
    for (int i = 0; i < 3; ++i) ++directed[{t[i], t[(i + 1) % 3]}];
  }
  int unmatched = 0, repeated = 0;
  for (const auto& [edge, count] : directed) {
    repeated += count != 1;
    unmatched += directed.count({edge.second, edge.first}) == 0;
  }
  EXPECT_EQ(repeated, 0);
  EXPECT_EQ(unmatched, 0);
}

TEST_P(VolumeTest, MeshVerticesAreSharedNotDuplicated) {
  TsdfVolume vol(params());
  integrate(vol, sphereView(0));
  const rekon::Mesh mesh = vol.extractMesh();
  ASSERT_GT(mesh.triangles.size(), 100u);
  std::set<std::tuple<float, float, float>> unique;
  for (const auto& v : mesh.vertices) unique.insert({v.x(), v.y(), v.z()});
  EXPECT_EQ(unique.size(), mesh.vertices.size());
  std::vector<int> uses(mesh.vertices.size(), 0);
  for (const auto& t : mesh.triangles) {
    for (int i = 0; i < 3; ++i) ++uses[t[i]];
  }
  // Inside a closed patch each vertex is shared by about 6 triangles; a soup would give exactly 1.
  EXPECT_GT(3.0 * mesh.triangles.size() / mesh.vertices.size(), 4.0);
}

TEST_P(VolumeTest, RaycastDepthMatchesTheSphere) {
  TsdfVolume vol(params());
  for (double a : {-20.0, 0.0, 20.0}) integrate(vol, sphereView(a));
  const View v = sphereView(0);
  const rekon::volume::RaycastImages ray = vol.raycast(k_, v.pose);
  const int cu = k_.width / 2, cv_ = k_.height / 2;
  EXPECT_NEAR(ray.depth.at<float>(cv_, cu), v.depth.at<float>(cv_, cu), 0.003);  // sphere front at 0.9 m
  const cv::Vec3f n = ray.normals.at<cv::Vec3f>(cv_, cu);
  EXPECT_LT(n[2], -0.95f);  // facing the camera, which looks along +z
  int compared = 0, close = 0;
  for (int y = 0; y < k_.height; y += 4) {
    for (int x = 0; x < k_.width; x += 4) {
      const float truth = v.depth.at<float>(y, x), got = ray.depth.at<float>(y, x);
      if (truth <= 0.f || got <= 0.f) continue;
      ++compared;
      close += std::abs(truth - got) < 0.005f;
    }
  }
  EXPECT_GT(compared, 600);
  EXPECT_GT(close, compared * 95 / 100);
}

TEST_P(VolumeTest, StreamingKeepsActiveBlocksBoundedAlongACorridor) {
  VolumeParams p = params();
  p.streaming_radius = 2.0;
  TsdfVolume vol(p);
  const rekon::Intrinsics k = rekon::test::smallCamera(80, 60);
  int64_t peak_recent = 0;
  for (int i = 0; i <= 40; ++i) {
    const Eigen::Vector3d eye(0.0, 0.0, 0.25 * i);  // 10 m along z, looking at the wall at x = 1.2
    const Pose pose = rekon::test::lookAt(eye, eye + Eigen::Vector3d(1.0, 0.3, 0.2));
    cv::Mat depth, color;
    rekon::test::renderCorridor(1.2, 1.0, k, pose, depth, color);
    vol.streamAround(eye);
    vol.integrate(depth, color, cv::Mat(), k, pose);
    if (i >= 20) peak_recent = std::max(peak_recent, vol.stats().active_blocks);
  }
  const auto s = vol.stats();
  EXPECT_GT(s.blocks, 3 * s.active_blocks);  // most of the corridor lives in the host store
  EXPECT_LT(peak_recent, s.blocks / 2);      // active blocks stay bounded while the total grows
  EXPECT_GT(s.streamed_out, 0);
}

// 41 views along a 10 m corridor (z), looking at the wall at x = 1.2; the
// volume streams around each eye before integrating. Returns the active
// blocks after each streamAround.
std::vector<int64_t> walkCorridor(TsdfVolume& vol, std::vector<Eigen::Vector3d>* eyes_out = nullptr) {
  const rekon::Intrinsics k = rekon::test::smallCamera(80, 60);
  std::vector<int64_t> active;
  for (int i = 0; i <= 40; ++i) {
    const Eigen::Vector3d eye(0.0, 0.0, 0.25 * i);
    const Pose pose = rekon::test::lookAt(eye, eye + Eigen::Vector3d(1.0, 0.3, 0.2));
    cv::Mat depth, color;
    rekon::test::renderCorridor(1.2, 1.0, k, pose, depth, color);
    vol.streamAround(eye);
    active.push_back(vol.stats().active_blocks);
    vol.integrate(depth, color, cv::Mat(), k, pose);
    if (eyes_out) eyes_out->push_back(eye);
  }
  return active;
}

TEST_P(VolumeTest, AnActiveBudgetKeepsBlocksOutsideTheSphereUntilItIsFullAndChangesNoVoxel) {
  // The same walk into a volume without a budget (every block outside the
  // sphere leaves at each streamAround) and one with a budget of twice the
  // sphere: its pool stays within the budget or the sphere, whichever is
  // larger, a round trip to the start and back streams nothing once both
  // ends fit, and the voxels are the same.
  VolumeParams p = params();
  p.streaming_radius = 2.0;
  TsdfVolume unbudgeted(p);
  std::vector<Eigen::Vector3d> eyes;
  const std::vector<int64_t> sphere = walkCorridor(unbudgeted, &eyes);
  // Twice the sphere once streamAround has left its sixteenth of the budget
  // free and streamed out a batch of another sixteenth.
  p.active_max_blocks = 2 * *std::max_element(sphere.begin(), sphere.end()) * 16 / 14 + 1;
  TsdfVolume budgeted(p);
  const std::vector<int64_t> active = walkCorridor(budgeted);
  for (size_t i = 0; i < active.size(); ++i)
    EXPECT_LE(active[i], std::max(p.active_max_blocks, sphere[i])) << "after streaming around view " << i;
  ASSERT_GT(budgeted.stats().streamed_out, 0) << "the walk must overflow the budget for this test to mean anything";
  EXPECT_LT(budgeted.stats().streamed_out, unbudgeted.stats().streamed_out);

  // A correction round at the start of the corridor, then back to the camera, twice.
  for (TsdfVolume* vol : {&unbudgeted, &budgeted}) {
    vol->streamAround(eyes.front());
    vol->streamAround(eyes.back());
  }
  const int64_t unbudgeted_in = unbudgeted.stats().streamed_in, budgeted_in = budgeted.stats().streamed_in;
  for (TsdfVolume* vol : {&unbudgeted, &budgeted}) {
    vol->streamAround(eyes.front());
    vol->streamAround(eyes.back());
  }
  EXPECT_GT(unbudgeted.stats().streamed_in, unbudgeted_in);  // without a budget each trip streams both ways
  EXPECT_EQ(budgeted.stats().streamed_in, budgeted_in);      // with one both ends stay
  expectSameVoxels(snapshot(unbudgeted), snapshot(budgeted));
}

TEST_P(VolumeTest, AHostBudgetSpillsTheFarthestBlocksToDiskAndReadsThemBackUnchanged) {
  // A host tier of 40 blocks (the walk streams out thousands): the rest go to
  // disk, come back for a walk to the start, and every voxel and the mesh
  // are those of a volume without the budget.
  rekon::test::TempDir dir;
  VolumeParams p = params();
  p.streaming_radius = 2.0;
  TsdfVolume unbudgeted(p);
  std::vector<Eigen::Vector3d> eyes;
  walkCorridor(unbudgeted, &eyes);
  p.host_max_blocks = 40;
  p.spill_dir = dir.path();
  TsdfVolume budgeted(p);
  walkCorridor(budgeted);
  const rekon::volume::VolumeStats s = budgeted.stats();
  EXPECT_GT(s.host_blocks_on_disk, s.host_blocks - 40);  // at most the budget in memory
  EXPECT_EQ(s.host_blocks, unbudgeted.stats().host_blocks);
  EXPECT_EQ(s.read_back_from_disk, 0);  // the walk never came back
  for (TsdfVolume* vol : {&unbudgeted, &budgeted}) vol->streamAround(eyes.front());
  EXPECT_GT(budgeted.stats().read_back_from_disk, 0);
  EXPECT_EQ(budgeted.stats().active_blocks, unbudgeted.stats().active_blocks);
  expectSameVoxels(snapshot(unbudgeted), snapshot(budgeted));
  EXPECT_EQ(budgeted.extractMesh().vertices.size(), unbudgeted.extractMesh().vertices.size());
  EXPECT_TRUE(std::filesystem::is_empty(dir.path())) << "the spill file is unlinked once open";
}

// The mesh's triangles as their corners' positions, each rotated to start at
// its smallest corner: equal for equal surfaces whatever the vertex order.
std::multiset<std::array<std::tuple<float, float, float>, 3>> triangleSet(const rekon::Mesh& m) {
  std::multiset<std::array<std::tuple<float, float, float>, 3>> out;
  for (const auto& t : m.triangles) {
    std::array<std::tuple<float, float, float>, 3> c;
    for (int i = 0; i < 3; ++i) c[i] = {m.vertices[t[i]].x(), m.vertices[t[i]].y(), m.vertices[t[i]].z()};
    std::rotate(c.begin(), std::min_element(c.begin(), c.end()), c.end());
    out.insert(c);
  }
  return out;
}

TEST_P(VolumeTest, AMeshInPiecesIsTheWholeMeshAndWritesTheSamePly) {
  // The corridor with most blocks on disk, meshed 7 blocks at a time (so
  // nearly every cube has vertices from another piece): the pieces together
  // are the one-piece mesh, vertex for vertex and triangle for triangle, and
  // PlyWriter's file reads back as that mesh.
  rekon::test::TempDir dir;
  VolumeParams p = params();
  p.streaming_radius = 2.0;
  p.host_max_blocks = 40;
  p.spill_dir = dir.path();
  TsdfVolume vol(p);
  walkCorridor(vol);
  ASSERT_GT(vol.stats().host_blocks_on_disk, 1000);
  rekon::Mesh whole, pieced;
  int pieces = 0;
  vol.extractMeshInPieces([&](const rekon::Mesh& piece) { rekon::appendMesh(whole, piece); }, 1 << 30);
  const std::string path = dir / "pieces.ply";
  rekon::PlyWriter ply(path, true);
  vol.extractMeshInPieces(
      [&](const rekon::Mesh& piece) {
        rekon::appendMesh(pieced, piece);
        ply.add(piece);
        ++pieces;
      },
      7);
  ply.finish();
  EXPECT_GT(pieces, vol.stats().blocks / 7);
  ASSERT_GT(whole.triangles.size(), 1000u);
  EXPECT_EQ(pieced.vertices.size(), whole.vertices.size()) << "a vertex shared across pieces was written twice";
  EXPECT_EQ(pieced.triangles.size(), whole.triangles.size());
  EXPECT_TRUE(triangleSet(pieced) == triangleSet(whole)) << "the pieces' triangles differ from the whole mesh's";
  const rekon::Mesh read = rekon::readPly(path);
  EXPECT_EQ(read.vertices, pieced.vertices);
  EXPECT_EQ(read.colors, pieced.colors);
  EXPECT_EQ(read.triangles, pieced.triangles);
  EXPECT_FALSE(std::filesystem::exists(path + ".vertices.tmp") || std::filesystem::exists(path + ".faces.tmp"));
}

TEST_P(VolumeTest, AHostTierThatCannotSpillNamesTheFileAndTheFix) {
  rekon::test::TempDir dir;
  VolumeParams p = params();
  p.streaming_radius = 2.0;
  p.host_max_blocks = 40;
  p.spill_dir = dir / "not_a_folder/voxels";
  { std::ofstream(dir / "not_a_folder") << "a file where the folder should be"; }
  TsdfVolume vol(p);
  try {
    walkCorridor(vol);
    FAIL() << "spilling into a path under a file must throw";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("not_a_folder/voxels/rekon_voxels_"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("mapper.voxel_spill_dir"), std::string::npos) << e.what();
  }
}

TEST_P(VolumeTest, InvalidPosesAreRejected) {
  TsdfVolume vol(params());
  View v = sphereView(0);
  Pose nan_pose = v.pose;
  nan_pose.translation().x() = std::nan("");
  EXPECT_THROW(vol.integrate(v.depth, v.color, cv::Mat(), k_, nan_pose), rekon::Error);
  Pose scaled = v.pose;
  scaled.linear() *= 1.1;  // not orthonormal
  EXPECT_THROW(vol.deintegrate(v.depth, v.color, cv::Mat(), k_, scaled), rekon::Error);
}

TEST_P(VolumeTest, ImagesOfTheWrongSizeOrTypeAreRejected) {
  TsdfVolume vol(params());
  const View v = sphereView(0);
  cv::Mat half;
  cv::Mat(v.depth, cv::Rect(0, 0, k_.width / 2, k_.height)).copyTo(half);
  EXPECT_THROW(vol.integrate(half, cv::Mat(), cv::Mat(), k_, v.pose), rekon::Error);
  cv::Mat raw(v.depth.size(), CV_16UC1, cv::Scalar(1000));
  EXPECT_THROW(vol.integrate(raw, cv::Mat(), cv::Mat(), k_, v.pose), rekon::Error);
}

TEST_P(VolumeTest, NegativeOrHugePixelWeightsAreRejected) {
  TsdfVolume vol(params());
  const View v = sphereView(0);
  cv::Mat weights(v.depth.size(), CV_32FC1, cv::Scalar(1.0f));
  weights.at<float>(3, 3) = -1.0f;
  EXPECT_THROW(vol.integrate(v.depth, v.color, weights, k_, v.pose), rekon::Error);
  weights.at<float>(3, 3) = 1e9f;  // beyond what a voxel's 21-bit weight can hold
  EXPECT_THROW(vol.integrate(v.depth, v.color, weights, k_, v.pose), rekon::Error);
  weights.at<float>(3, 3) = std::nanf("");
  EXPECT_THROW(vol.integrate(v.depth, v.color, weights, k_, v.pose), rekon::Error);
  EXPECT_EQ(vol.stats().blocks, 0);  // rejected before anything was integrated
}

INSTANTIATE_TEST_SUITE_P(Backends, VolumeTest, ::testing::ValuesIn(rekon::volume::availableBackends()),
                         [](const ::testing::TestParamInfo<std::string>& p) { return p.param; });

TEST(VolumeConfig, DefaultsMatchTheNamedDefaultsAndBadValuesNameTheKey) {
  const VolumeParams p = rekon::volume::volumeParamsFromConfig(rekon::Config::load());
  EXPECT_DOUBLE_EQ(p.voxel_size, VolumeParams::kDefaultVoxelSize);
  EXPECT_DOUBLE_EQ(p.truncation, VolumeParams::kDefaultTruncation);
  EXPECT_DOUBLE_EQ(p.max_depth, VolumeParams::kDefaultMaxDepth);
  EXPECT_EQ(p.block_capacity, VolumeParams::kDefaultBlockCapacity);
  EXPECT_EQ(p.allocation_stride, VolumeParams::kDefaultAllocationStride);
  EXPECT_DOUBLE_EQ(p.weight_units, VolumeParams::kDefaultWeightUnits);
  try {
    rekon::volume::volumeParamsFromConfig(rekon::Config::load("", {"volume.truncation=0.001"}));
    FAIL() << "a truncation below the voxel size must be rejected";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("volume.truncation"), std::string::npos) << e.what();
  }
}

TEST(DepthToMetres, DividesByTheDepthScale) {
  cv::Mat raw(2, 2, CV_16UC1, cv::Scalar(0));
  raw.at<uint16_t>(0, 1) = 5000;
  raw.at<uint16_t>(1, 0) = 2500;
  const cv::Mat m = rekon::volume::depthToMetres(raw, 5000.0);
  EXPECT_EQ(m.type(), CV_32FC1);
  EXPECT_FLOAT_EQ(m.at<float>(0, 1), 1.0f);
  EXPECT_FLOAT_EQ(m.at<float>(1, 0), 0.5f);
  EXPECT_FLOAT_EQ(m.at<float>(0, 0), 0.0f);  // 0 stays "no measurement"
  EXPECT_THROW(rekon::volume::depthToMetres(cv::Mat(2, 2, CV_32FC1), 5000.0), rekon::Error);
}

}  // namespace
