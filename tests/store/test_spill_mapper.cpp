// The short version of the long corridor run: the mapping core over 300
// corridor frames with a keyframe store far too small for them, so most
// keyframes spill; a restarted mapper rebuilds the same volume from the store.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <map>

#include "rekon/mapper/mapper.hpp"
#include "rekon/synth/synth.hpp"
#include "test_support.hpp"

using namespace rekon;

namespace {

constexpr int kFrames = 300;  // 10 s of the corridor walk, about 3 m
constexpr int kDvoEvery = 10; // frames per (replayed) DVO keyframe

Intrinsics smallCamera() { return synth::defaultIntrinsics().atLevel(2); }  // 160x120: 211200 bytes a keyframe

mapper::MapperParams params(const std::string& segment, const std::string& spill_dir) {
  mapper::MapperParams p;
  p.fusion.kappa = 5;  // 300 frames -> 60 KF keyframes
  p.volume.voxel_size = 0.02;
  p.volume.truncation = 0.08;
  p.volume.streaming_radius = 2.0;
  p.volume.backend = "cpu";
  p.volume.cpu_threads = 2;
  p.use_store = true;
  p.resume = true;
  p.store.segment = segment;
  p.store.size_mb = 1;  // 4 of those keyframes: the other 56 spill
  p.store.spill_dir = spill_dir;
  return p;
}

std::map<std::tuple<int, int, int>, std::vector<volume::Voxel>> snapshot(const volume::TsdfVolume& v) {
  std::map<std::tuple<int, int, int>, std::vector<volume::Voxel>> out;
  for (const volume::BlockCoord& c : v.blockCoords()) {
    std::vector<volume::Voxel> voxels;
    if (v.readBlock(c, voxels)) out[{c.x, c.y, c.z}] = voxels;
  }
  return out;
}

bool sameVoxels(const std::vector<volume::Voxel>& a, const std::vector<volume::Voxel>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (volume::voxelWeight(a[i]) != volume::voxelWeight(b[i]) || a[i].sdf_sum != b[i].sdf_sum) return false;
  return true;
}

}  // namespace

TEST(KeyframeStoreSpill, ARestartedMapperRebuildsTheSameVolumeFromSpilledKeyframes) {
  test::TempDir dir;
  const std::string segment = "rekon_test_spill_mapper_" + std::to_string(getpid());
  store::KeyframeStore::remove(segment);
  const auto scene = synth::Scene::make("corridor");
  const Trajectory gt = scene->trajectory(kFrames, 1);
  std::map<std::tuple<int, int, int>, std::vector<volume::Voxel>> before;
  {
    mapper::Mapper first(params(segment, dir / "spill"));
    for (int i = 0; i < kFrames; ++i) {
      const int anchor = i / kDvoEvery;
      const Pose anchor_pose = gt[static_cast<size_t>(anchor * kDvoEvery)].pose;
      if (i % kDvoEvery == 0) first.setKeyframeEstimate(anchor, anchor_pose);
      RgbdFrame f = scene->render(smallCamera(), gt[static_cast<size_t>(i)].pose, synth::Noise::Kinect, 100 + i, 2);
      f.id = i;
      f.timestamp = gt[static_cast<size_t>(i)].timestamp;
      first.addFrame(f, smallCamera(), anchor, anchor_pose.inverse() * gt[static_cast<size_t>(i)].pose, false);
    }
    first.flush();
    EXPECT_EQ(first.counters().kf_keyframes, kFrames / 5);
    before = snapshot(first.volume());
  }  // no removeStore(): as after a crash
  const auto store = store::KeyframeStore::openExisting(segment);
  const store::StoreUsage u = store->usage();
  EXPECT_EQ(u.keyframes, 60u);
  EXPECT_EQ(u.resident, 4u);  // 1 MiB holds 4 keyframes of 211200 bytes
  EXPECT_EQ(u.spilled, 56u);
  // The newest keyframes stay in shared memory: the camera walked away from the others.
  for (const auto& info : store->list()) EXPECT_EQ(info.spilled, info.id < 56) << info.id;

  mapper::Mapper restarted(params(segment, dir / "spill"));
  EXPECT_EQ(restarted.counters().restored_keyframes, 60);
  EXPECT_EQ(restarted.counters().rebuilt_keyframes, 0);  // rebuilt beside the new frames, not before them
  restarted.completeRebuild();
  EXPECT_EQ(restarted.counters().rebuilt_keyframes, 60);
  const auto after = snapshot(restarted.volume());
  EXPECT_GT(before.size(), 100u);  // a real surface
  ASSERT_EQ(after.size(), before.size());
  size_t differing = 0;
  for (const auto& [coord, voxels] : before) {
    const auto it = after.find(coord);
    differing += it == after.end() || !sameVoxels(voxels, it->second);
  }
  EXPECT_EQ(differing, 0u);  // integer weights and sums: the same keyframes at the same poses give the same voxels
  restarted.removeStore();
  EXPECT_FALSE(std::filesystem::exists(dir / ("spill/" + segment + "_kf_0.rks")));
}
