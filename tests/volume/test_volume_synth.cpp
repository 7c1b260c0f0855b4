// The volume on rekon's synthetic scenes (tools/synth) against their exact
// surfaces (tools/eval): small images and few frames to stay fast.
#include <gtest/gtest.h>

#include "rekon/eval/surface_eval.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"
#include "rekon/synth/synth.hpp"
#include "test_support.hpp"

namespace {

using rekon::volume::TsdfVolume;
using rekon::volume::VolumeParams;

struct SynthFrame {
  cv::Mat depth, color;
  rekon::Pose pose;
};

class SynthVolumeTest : public ::testing::TestWithParam<std::string> {
 protected:
  // Every 30th frame of the room's trajectory (one per second), at 320x240.
  std::vector<SynthFrame> roomFrames(int count) {
    scene_ = rekon::synth::Scene::make("room");
    k_ = rekon::synth::defaultIntrinsics().atLevel(1);
    const rekon::Trajectory trajectory = scene_->trajectory(scene_->defaultFrames(), 1);
    std::vector<SynthFrame> frames;
    for (int i = 0; i < count; ++i) {
      const rekon::Pose& pose = trajectory.at(static_cast<size_t>(i) * 30 % trajectory.size()).pose;
      const rekon::RgbdFrame f = scene_->render(k_, pose, rekon::synth::Noise::None, 1);
      frames.push_back({rekon::volume::depthToMetres(f.depth, k_.depth_scale), f.color, pose});
    }
    return frames;
  }
  VolumeParams params() const {
    VolumeParams p;
    p.backend = GetParam();
    return p;
  }

  std::unique_ptr<rekon::synth::Scene> scene_;
  rekon::Intrinsics k_;
};

TEST_P(SynthVolumeTest, NoiselessRoomFusesWithinThreeMillimetresOfItsTrueSurface) {
  const auto frames = roomFrames(12);
  TsdfVolume volume(params());  // 1 cm voxels, 4 cm truncation
  for (const auto& f : frames) volume.integrate(f.depth, f.color, cv::Mat(), k_, f.pose);
  const rekon::Mesh mesh = volume.extractMesh();
  ASSERT_GT(mesh.vertices.size(), 10000u);
  rekon::eval::SurfaceEvalOptions options;
  options.reference_samples = rekon::eval::SurfaceEvalOptions::kMinSamples;
  const auto errors = rekon::eval::evaluateSurface(mesh, scene_->groundTruthMesh(), options);
  EXPECT_LT(errors.corr_m, 0.003);  // the quality goal (CORR <= 3 mm at 1 cm voxels)
  EXPECT_GT(errors.corr_within_1cm, 0.98);
}

TEST_P(SynthVolumeTest, RoomFramesDeintegratedInReverseOrderLeaveNothing) {
  const auto frames = roomFrames(6);
  TsdfVolume volume(params());
  for (const auto& f : frames) volume.integrate(f.depth, f.color, cv::Mat(), k_, f.pose);
  ASSERT_GT(volume.stats().blocks, 1000);
  for (auto it = frames.rbegin(); it != frames.rend(); ++it) volume.deintegrate(it->depth, it->color, cv::Mat(), k_, it->pose);
  EXPECT_EQ(volume.stats().blocks, 0);
}

INSTANTIATE_TEST_SUITE_P(Backends, SynthVolumeTest, ::testing::ValuesIn(rekon::volume::availableBackends()),
                         [](const ::testing::TestParamInfo<std::string>& p) { return p.param; });

}  // namespace
