// The building scene (issue 49): size, loops, clearance, ground truth and
// the size of its voxel map against the mapper's budgets.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "rekon/eval/surface_eval.hpp"
#include "rekon/synth/synth.hpp"

namespace {

using rekon::synth::Noise;
using rekon::synth::Scene;

constexpr double kDeg = std::numbers::pi / 180.0;

const Scene& building() {
  static const auto scene = Scene::make("building");
  return *scene;
}

const rekon::Mesh& buildingMesh() {
  static const rekon::Mesh mesh = building().groundTruthMesh();
  return mesh;
}

TEST(Building, IsAtLeast30By20Metres) {
  Eigen::Vector3f lo = buildingMesh().vertices.front(), hi = lo;
  for (const auto& v : buildingMesh().vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  EXPECT_FLOAT_EQ(hi.x() - lo.x(), 40.0f);  // issue 49 asks for at least 30 x 20 m
  EXPECT_FLOAT_EQ(hi.y() - lo.y(), 24.0f);
  EXPECT_FLOAT_EQ(hi.z() - lo.z(), 2.7f);
}

TEST(Building, AnHourIs108000FramesAndTheWalkGoesOnForThem) {
  const auto t = building().trajectory(108000, 1, 1);
  ASSERT_EQ(t.size(), 108000u);
  EXPECT_NEAR(t.back().timestamp, 107999 / 30.0, 1e-9);
  // Still walking at the end (further laps were added), not standing still.
  EXPECT_GT(rekon::translationDistance(t[t.size() - 301].pose, t.back().pose), 1.0);
}

TEST(Building, ThreeLapsRevisitEveryPlaceTheFirstLapSaw) {
  // Laps A, B, C; a pose counts as a revisit when one at least 60 s older was
  // within 1 m and 45 degrees of heading (where the tracker looks for loops).
  const auto t = building().trajectory(building().defaultFrames(3), 1, 3);
  int revisits = 0, later = 0;
  for (size_t i = 1800; i < t.size(); i += 30) {
    ++later;
    for (size_t j = 0; j + 1800 <= i; j += 10) {
      if (rekon::translationDistance(t[i].pose, t[j].pose) < 1.0 && rekon::rotationAngle(t[i].pose, t[j].pose) < 45 * kDeg) {
        ++revisits;
        break;
      }
    }
  }
  // Measured: 0.26 of the poses after the first minute revisit a place (laps B and C cross
  // and retrace lap A); the bound leaves a quarter of that as margin.
  EXPECT_GT(static_cast<double>(revisits) / later, 0.2);
}

TEST(Building, PeakSpeedsStayThoseOfAHandHeldCamera) {
  const auto t = building().trajectory(building().defaultFrames(1), 1, 1);
  double vmax = 0, wmax = 0;
  for (size_t i = 1; i < t.size(); ++i) {
    const double dt = t[i].timestamp - t[i - 1].timestamp;
    vmax = std::max(vmax, rekon::translationDistance(t[i - 1].pose, t[i].pose) / dt);
    wmax = std::max(wmax, rekon::rotationAngle(t[i - 1].pose, t[i].pose) / dt);
  }
  // The same bounds as the corridor's: measured 0.554 m/s, 20.1 degree/s.
  EXPECT_LT(vmax, 0.6);
  EXPECT_LT(wmax, 35 * kDeg);
}

TEST(Building, TheCameraNeverComesNearerThanTheKinectsMinimumDepth) {
  // Every second of lap A at 80 x 60: furniture, door jambs and corners stay beyond 0.4 m.
  const auto k = rekon::synth::defaultIntrinsics().atLevel(3);
  const auto t = building().trajectory(building().defaultFrames(1), 1, 1);
  double nearest = 1e9;
  for (size_t i = 0; i < t.size(); i += 30) {
    const auto f = building().render(k, t[i].pose, Noise::None, 1, 1);
    for (int y = 0; y < f.depth.rows; ++y)
      for (int x = 0; x < f.depth.cols; ++x)
        if (const uint16_t d = f.depth.at<uint16_t>(y, x); d > 0) nearest = std::min(nearest, d / k.depth_scale);
  }
  EXPECT_GT(nearest, 0.4);
}

TEST(Building, DepthRenderedAtGroundTruthPosesLiesOnTheGroundTruthMesh) {
  const auto k = rekon::synth::defaultIntrinsics().atLevel(2);
  const auto t = building().trajectory(building().defaultFrames(3), 1, 3);
  rekon::Mesh cloud;
  for (size_t i = 0; i < t.size(); i += t.size() / 12) {
    const auto f = building().render(k, t[i].pose, Noise::None, 1, 1);
    for (int y = 0; y < k.height; y += 2) {
      for (int x = 0; x < k.width; x += 2) {
        const double z = f.depth.at<uint16_t>(y, x) / k.depth_scale;
        if (z <= 0 || z > 6.0) continue;
        const Eigen::Vector3d p(z * (x - k.cx) / k.fx, z * (y - k.cy) / k.fy, z);
        cloud.vertices.push_back((t[i].pose * p).cast<float>());
      }
    }
  }
  ASSERT_GT(cloud.vertices.size(), 5000u);
  // The reference cut to what lies within 7 m of the camera positions (a smaller BVH, a faster test).
  rekon::Mesh near = buildingMesh();
  std::erase_if(near.triangles, [&](const Eigen::Vector3i& tri) {
    const Eigen::Vector3d c = near.vertices[static_cast<size_t>(tri[0])].cast<double>();
    for (size_t i = 0; i < t.size(); i += t.size() / 12)
      if ((c - t[i].pose.translation()).norm() < 7.0) return false;
    return true;
  });
  const auto e = rekon::eval::evaluateSurface(cloud, near);
  // Quantisation 0.1 mm and float ray casting; cells at hidden-cell borders are 5 cm coarse.
  EXPECT_LT(e.corr_m, 1e-3);
}

TEST(SurfaceBand, AFlatSquareFillsTwoLayersOfBlocks) {
  // 1 x 1 m at z = 2 cm: 13 x 13 blocks of 8 cm in x, y; the band [-2, 6] cm crosses z = 0.
  rekon::Mesh m;
  m.vertices = {{0, 0, 0.02f}, {0.999f, 0, 0.02f}, {0.999f, 0.999f, 0.02f}, {0, 0.999f, 0.02f}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  EXPECT_EQ(rekon::synth::surfaceBandBlocks(m, {0.01, 0.04, 8, 1e9}), 13 * 13 * 2);
  EXPECT_EQ(rekon::synth::surfaceBandBlocks(m, {0.01, 0.04, 8, 0.0}), 0);  // above max_z: left out
}

TEST(Building, ItsMapAt1cmIsLargerThanTheMappersActivePlusHostBudgets) {
  // mapper.active_mb 1024 + host_mb 1024 = 2048 MiB of 6 KiB blocks = 349,525 blocks (the defaults
  // are smaller since 2026-12-07: 1024 + 256); beyond them the disk tier holds the rest. Without the ceiling (never within 4 m of
  // the walk's camera) measured 777,197 blocks (4554 MiB).
  const int64_t blocks = rekon::synth::surfaceBandBlocks(buildingMesh(), {0.01, 0.04, 8, 2.65});
  EXPECT_GT(blocks, 2 * 349525);
}

}  // namespace
