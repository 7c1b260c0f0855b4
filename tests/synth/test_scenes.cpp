// Scenes, rendering and trajectories of the synthetic ground truth.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <opencv2/core.hpp>

#include "rekon/common/error.hpp"
#include "rekon/eval/surface_eval.hpp"
#include "rekon/synth/synth.hpp"

namespace {

using rekon::Pose;
using rekon::synth::Noise;
using rekon::synth::Scene;

constexpr double kDeg = std::numbers::pi / 180.0;

// Camera-to-world pose in the scenes' z-up world looking along `yaw`, tilted by `pitch`.
Pose lookPose(const Eigen::Vector3d& eye, double yaw, double pitch) {
  const Eigen::Vector3d forward(std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw), std::sin(pitch));
  const Eigen::Vector3d right = forward.cross(Eigen::Vector3d::UnitZ()).normalized();
  Pose p = Pose::Identity();
  p.linear().col(0) = right;
  p.linear().col(1) = forward.cross(right);
  p.linear().col(2) = forward;
  p.translation() = eye;
  return p;
}

double depthAt(const rekon::RgbdFrame& f, int x, int y, double scale) { return f.depth.at<uint16_t>(y, x) / scale; }

TEST(Synth, ExactDepthEqualsTheAnalyticDepthOfTheFloorWithinQuantisation) {
  // Tabletop, looking down at 60 degrees at an empty stretch of floor (z = 0).
  const auto scene = Scene::make("tabletop");
  const rekon::Intrinsics k = rekon::synth::defaultIntrinsics();
  const Pose pose = lookPose({1.0, -1.0, 1.2}, -45 * kDeg, -60 * kDeg);
  const auto frame = scene->render(k, pose, Noise::None, 1);
  for (int y = 200; y <= 280; y += 20) {
    for (int x = 280; x <= 360; x += 20) {
      const Eigen::Vector3d ray = pose.linear() * Eigen::Vector3d((x - k.cx) / k.fx, (y - k.cy) / k.fy, 1.0);
      const double z = -pose.translation().z() / ray.z();  // ray parameter = camera depth (ray z_cam = 1)
      // Half a quantisation step (0.1 mm at depth_scale 5000) plus float ray casting.
      EXPECT_NEAR(depthAt(frame, x, y, k.depth_scale), z, 0.5 / k.depth_scale + 2e-5) << "pixel " << x << "," << y;
    }
  }
}

TEST(Synth, ExactDepthOfAFrontoParallelWallIsItsDistance) {
  // Room, from its centre towards the +x wall 3 m away; pixel (100, 240) sees bare wall.
  const auto scene = Scene::make("room");
  const rekon::Intrinsics k = rekon::synth::defaultIntrinsics();
  const auto frame = scene->render(k, lookPose({0, 0, 1.4}, 0, 0), Noise::None, 1);
  EXPECT_EQ(frame.depth.at<uint16_t>(240, 100), 15000);  // 3 m * 5000
  EXPECT_EQ(frame.depth.type(), CV_16UC1);
  EXPECT_EQ(frame.color.type(), CV_8UC3);
}

TEST(Synth, RenderedSurfaceLiesOnTheGroundTruthMesh) {
  // Back-projected exact depth must lie on mesh_gt within quantisation and float error.
  const auto scene = Scene::make("tabletop");
  const rekon::Intrinsics k = rekon::synth::defaultIntrinsics().atLevel(2);
  const auto traj = scene->trajectory(scene->defaultFrames(), 1);
  rekon::Mesh cloud;
  for (size_t i : {size_t{0}, traj.size() / 2}) {
    const auto frame = scene->render(k, traj[i].pose, Noise::None, 1);
    for (int y = 0; y < k.height; ++y) {
      for (int x = 0; x < k.width; ++x) {
        const double z = depthAt(frame, x, y, k.depth_scale);
        if (z <= 0) continue;
        const Eigen::Vector3d p(z * (x - k.cx) / k.fx, z * (y - k.cy) / k.fy, z);
        cloud.vertices.push_back((traj[i].pose * p).cast<float>());
      }
    }
  }
  const auto errors = rekon::eval::evaluateSurface(cloud, scene->groundTruthMesh());
  // Mean distance well under a millimetre (quantisation 0.1 mm, curved faces 0.2 mm);
  // hidden-cell boundaries of the mesh are 2 cm coarse, hence the 99 % bound.
  EXPECT_LT(errors.corr_m, 1e-3);
  EXPECT_GT(errors.corr_within_1cm, 0.99);
}

TEST(Synth, KinectNoiseKeepsDepthNearTheTruthAndDropsBeyondFourMetres) {
  const auto scene = Scene::make("room");
  const rekon::Intrinsics k = rekon::synth::defaultIntrinsics().atLevel(1);
  // Along the room's 6 m diagonal: the far corner is more than 4 m away.
  const Pose pose = lookPose({-1.0, -1.0, 1.4}, 38 * kDeg, -5 * kDeg);
  const auto exact = scene->render(k, pose, Noise::None, 1);
  const auto noisy = scene->render(k, pose, Noise::Kinect, 1);
  int far = 0, far_valid = 0, near = 0, near_valid = 0, outliers = 0;
  for (int y = 0; y < k.height; ++y) {
    for (int x = 0; x < k.width; ++x) {
      const double z = depthAt(exact, x, y, k.depth_scale), zn = depthAt(noisy, x, y, k.depth_scale);
      if (z > 4.0) {
        ++far;
        far_valid += zn > 0;
        continue;
      }
      if (z < 0.4) continue;
      ++near;
      if (zn <= 0) continue;
      ++near_valid;
      // 5 sigma of the axial noise plus one disparity step (z^2 / (0.075 * 580 * 8)).
      const double sigma = 0.0012 + 0.0019 * (z - 0.4) * (z - 0.4);
      outliers += std::abs(zn - z) > 5 * sigma + z * z / (0.075 * 580 * 8);
    }
  }
  ASSERT_GT(far, 100) << "the view must reach beyond 4 m";
  EXPECT_EQ(far_valid, 0);
  EXPECT_GT(near_valid, near * 8 / 10) << "most depth within range stays valid";
  EXPECT_LT(near_valid, near) << "some depth drops out at edges and grazing angles";
  EXPECT_LT(outliers, near_valid / 1000 + 1);
}

TEST(Synth, RenderingIsDeterministicForASeedAndVariesAcrossSeeds) {
  const auto scene = Scene::make("tabletop");
  const rekon::Intrinsics k = rekon::synth::defaultIntrinsics().atLevel(2);
  const Pose pose = scene->trajectory(1, 1)[0].pose;
  const auto a = scene->render(k, pose, Noise::Kinect, 7, 1);
  const auto b = scene->render(k, pose, Noise::Kinect, 7, 2);  // thread count must not matter
  const auto c = scene->render(k, pose, Noise::Kinect, 8, 2);
  EXPECT_EQ(cv::norm(a.depth, b.depth, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.color, b.color, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(a.depth, c.depth, cv::NORM_INF), 0.0);
}

TEST(Synth, RoomTrajectoryClosesItsLoop) {
  const auto scene = Scene::make("room");
  const auto traj = scene->trajectory(scene->defaultFrames(), 3);
  ASSERT_EQ(traj.size(), 600u);
  EXPECT_LT(rekon::translationDistance(traj.front().pose, traj.back().pose), 1e-6);
  EXPECT_LT(rekon::rotationAngle(traj.front().pose, traj.back().pose), 1e-6);
  // ...after going around: it was far from the start half way.
  EXPECT_GT(rekon::translationDistance(traj.front().pose, traj[300].pose), 1.5);
}

TEST(Synth, TrajectoriesAreAt30HzAndTrackable) {
  for (const std::string name : {"tabletop", "room", "corridor"}) {
    const auto scene = Scene::make(name);
    const auto traj = scene->trajectory(scene->defaultFrames(), 1);
    ASSERT_EQ(static_cast<int>(traj.size()), scene->defaultFrames()) << name;
    for (size_t i = 1; i < traj.size(); ++i) {
      ASSERT_NEAR(traj[i].timestamp, i / 30.0, 1e-9) << name;
      ASSERT_TRUE(rekon::isValidPose(traj[i].pose, 1e-9)) << name;
      // Hand-held speeds a dense tracker follows: about 0.5 m/s and 30 deg/s at most.
      ASSERT_LT(rekon::translationDistance(traj[i - 1].pose, traj[i].pose) * 30.0, 0.6) << name << " frame " << i;
      ASSERT_LT(rekon::rotationAngle(traj[i - 1].pose, traj[i].pose) * 30.0 / kDeg, 35.0) << name << " frame " << i;
    }
  }
}

TEST(Synth, CorridorWalksAtLeastSixtyMetresOutAndBack) {
  const auto scene = Scene::make("corridor");
  const auto traj = scene->trajectory(scene->defaultFrames(), 1);
  double path = 0, farthest = 0;
  for (size_t i = 1; i < traj.size(); ++i) {
    path += rekon::translationDistance(traj[i - 1].pose, traj[i].pose);
    farthest = std::max(farthest, rekon::translationDistance(traj.front().pose, traj[i].pose));
  }
  EXPECT_GE(path, 60.0);
  EXPECT_GE(farthest, 29.0);
  EXPECT_LT(rekon::translationDistance(traj.front().pose, traj.back().pose), 1.5) << "it comes back";
}

TEST(Synth, CorridorLapsGoRoundTheSameOvalAgain) {
  const auto scene = Scene::make("corridor");
  const int one = scene->defaultFrames(1), three = scene->defaultFrames(3);
  EXPECT_GT(scene->defaultFrames(2), 10000);  // the long-run sequences: 2 laps are already 10 000 frames
  const auto single = scene->trajectory(one, 1), laps = scene->trajectory(three, 1, 3);
  ASSERT_EQ(static_cast<int>(laps.size()), three);
  // The first lap is the one-lap walk until the laps slow down for the near-end turn (2.5 m, some 7 s, before it).
  for (int i = 0; i < one - 300; ++i) ASSERT_TRUE(laps[i].pose.isApprox(single[i].pose, 1e-12)) << i;
  // Every lap passes the start again in the outbound lane, and no faster than one lap's limits.
  int passes = 0;
  bool near = true;
  for (size_t i = 1; i < laps.size(); ++i) {
    ASSERT_TRUE(rekon::isValidPose(laps[i].pose, 1e-9));
    ASSERT_LT(rekon::translationDistance(laps[i - 1].pose, laps[i].pose) * 30.0, 0.6) << "frame " << i;
    ASSERT_LT(rekon::rotationAngle(laps[i - 1].pose, laps[i].pose) * 30.0 / kDeg, 35.0) << "frame " << i;
    const bool now = rekon::translationDistance(laps.front().pose, laps[i].pose) < 0.3;
    passes += now && !near;
    near = now;
  }
  EXPECT_EQ(passes, 2);  // at the start of laps 2 and 3
  // It ends where one lap ends: back at the near end, in the return lane.
  EXPECT_LT((laps.back().pose.translation() - single.back().pose.translation()).head<2>().norm(), 0.05);
}

TEST(Synth, LapsAreForTheCorridorOnly) {
  try {
    Scene::make("room")->trajectory(100, 1, 2);
    FAIL() << "expected rekon::Error";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("--laps is for the corridor"), std::string::npos) << e.what();
  }
  EXPECT_THROW(Scene::make("corridor")->defaultFrames(0), rekon::Error);
}

TEST(Synth, TrajectoryIsDeterministicForASeed) {
  const auto scene = Scene::make("room");
  const auto a = scene->trajectory(50, 5), b = scene->trajectory(50, 5), c = scene->trajectory(50, 6);
  for (size_t i = 0; i < a.size(); ++i) EXPECT_TRUE(a[i].pose.isApprox(b[i].pose, 0));
  EXPECT_FALSE(a[10].pose.isApprox(c[10].pose, 1e-9));
}

TEST(Synth, DriftedTrajectoryStartsAtTheTruthAndWandersOff) {
  const auto scene = Scene::make("room");
  const auto gt = scene->trajectory(300, 1);
  const auto none = rekon::synth::driftedTrajectory(gt, 0.0, 0.0, 1);
  const auto drifted = rekon::synth::driftedTrajectory(gt, 0.02, 1.0, 1);
  EXPECT_LT(rekon::translationDistance(none.back().pose, gt.back().pose), 1e-9);
  EXPECT_TRUE(drifted.front().pose.isApprox(gt.front().pose, 0));
  EXPECT_GT(rekon::translationDistance(drifted.back().pose, gt.back().pose), 1e-3);
}

TEST(Synth, GroundTruthMeshIsColoredAndInsideTheScene) {
  const auto mesh = Scene::make("tabletop")->groundTruthMesh();
  ASSERT_GT(mesh.triangles.size(), 1000u);
  ASSERT_EQ(mesh.colors.size(), mesh.vertices.size());
  for (const auto& v : mesh.vertices) {
    ASSERT_TRUE(v.x() >= -2.0f && v.x() <= 2.0f && v.y() >= -2.0f && v.y() <= 2.0f && v.z() >= 0.0f && v.z() <= 2.5f);
  }
}

TEST(Synth, UnknownSceneErrorNamesTheChoices) {
  try {
    Scene::make("kitchen");
    FAIL() << "expected rekon::Error";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("room, corridor, tabletop or building"), std::string::npos) << e.what();
  }
}

}  // namespace
