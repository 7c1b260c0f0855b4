// The mapper's mesh publisher in-process over a memory:// bus (issue 17): the
// byte budget holds back what it cannot carry, finish() sends it all so a
// subscriber ends with extractMesh()'s surface, and a MESH_REQUEST brings a
// full snapshot of every block.
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <iostream>
#include <cmath>
#include <set>
#include <string>
#include <thread>
#include <tuple>

#include "mesh_publisher.hpp"
#include "rekon/common/bus.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/common/service.hpp"
#include "rekon/synth/synth.hpp"
#include "rekon_msgs/mesh_blocks_t.hpp"
#include "rekon_msgs/mesh_request_t.hpp"

namespace rekon::mapper {
namespace {

constexpr int kFrames = 24;  // 6 KF keyframes at kappa 4

Intrinsics testCamera() { return synth::defaultIntrinsics().atLevel(1); }

MapperParams testParams() {
  MapperParams p;
  p.fusion.kappa = 4;
  p.volume.backend = "cpu";
  p.volume.cpu_threads = 2;
  return p;
}

// Every frame at its true pose, all in DVO keyframe 0 at the origin.
void play(Mapper& mapper, MeshPublisher& publisher) {
  const auto scene = synth::Scene::make("tabletop");
  const Trajectory truth = scene->trajectory(kFrames, 3);
  mapper.setKeyframeEstimate(0, Pose::Identity());
  for (int i = 0; i < kFrames; ++i) {
    RgbdFrame f = scene->render(testCamera(), truth[i].pose, synth::Noise::None, 100 + i, 2);
    f.id = i;
    f.timestamp = truth[i].timestamp;
    mapper.addFrame(f, testCamera(), 0, truth[i].pose, false);
    publisher.tick(mapper);
  }
}

using Quanta = std::set<std::tuple<long long, long long, long long>>;
Quanta quantaOf(const Mesh& mesh, double quantum) {
  Quanta out;
  const double per_metre = 1.0 / quantum;
  for (const auto& v : mesh.vertices) out.insert({std::llround(v.x() * per_metre), std::llround(v.y() * per_metre), std::llround(v.z() * per_metre)});
  return out;
}

class MeshPublisherTest : public ::testing::Test {
 protected:
  MeshPublisherTest()
      : url_("memory://mesh_publisher_" + std::to_string(getpid()) + "_" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name()),
        args_("rekon-mapper", "in-process"),
        ctx_("mapper", Config::load("", {"lcm.url=" + url_}), "", args_),
        subscriber_(makeBus(BusOptions::fromConfig(Config::load("", {"lcm.url=" + url_})))) {
    subscriber_->subscribe<rekon_msgs::mesh_blocks_t>(channel::kMeshBlocks, [this](const rekon_msgs::mesh_blocks_t& m) {
      map_.apply(m);
      bytes_ += m.getEncodedSize();
      full_ += m.full ? 1 : 0;
      blocks_ += m.num_blocks;
      for (const BlockMesh& b : decodeMeshBlocks(m)) ++causes_[static_cast<int>(b.cause)];
    });
  }
  void receiveAll() {
    while (subscriber_->handle(0)) {
    }
  }

  std::string url_;
  ArgParser args_;
  ServiceContext ctx_;
  std::unique_ptr<Bus> subscriber_;
  MeshMap map_;
  int64_t bytes_ = 0, full_ = 0, blocks_ = 0;
  std::array<int64_t, kMaxBlockCause + 1> causes_{};  // blocks received per cause
};

TEST_F(MeshPublisherTest, TheBudgetHoldsBlocksBackAndFinishSendsEveryOneSoTheSubscriberHasTheMapperMesh) {
  Mapper mapper(testParams());
  MeshPublisherSettings settings;
  settings.rate_hz = 100;             // the budget, not the rate, limits here
  settings.max_bytes_per_s = 1e4;     // the least allowed: far below what 6 KF keyframes change
  MeshPublisher publisher(ctx_, settings, testParams().volume);
  const auto t0 = std::chrono::steady_clock::now();
  play(mapper, publisher);
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  receiveAll();
  // At most the first tick's allowance (budget / rate), the budget over the
  // time played, and one update's overdraw (its blocks are chosen by the
  // running bytes-per-block estimate). Measured: 8.6-19.7 KB in 0.8-2.0 s,
  // right at the budget; 16 KB (~25 blocks) is the margin for the overdraw.
  // Everything, sent by finish(), is 1.4 MB.
  const double bound = 1e4 / 100 + 1e4 * elapsed + 16e3;
  std::cout << "budgeted: " << bytes_ << " bytes in " << elapsed << " s (bound " << bound << ")\n";
  EXPECT_LE(static_cast<double>(bytes_), bound);
  EXPECT_GT(publisher.stats().pending, 0);
  publisher.finish(mapper, BlockCause::kFinalPass);
  receiveAll();
  EXPECT_EQ(publisher.stats().pending, 0);
  std::cout << "with the rest after the final update: " << bytes_ << " bytes\n";
  const Mesh whole = mapper.extractMesh();
  const Mesh assembled = map_.toMesh();
  const double quantum = 0.01 / 1024;  // volume.voxel_size / 1024
  EXPECT_EQ(quantaOf(assembled, quantum), quantaOf(whole, quantum));
  EXPECT_EQ(assembled.triangles.size(), whole.triangles.size());
  EXPECT_EQ(publisher.stats().bytes, bytes_);
  EXPECT_GT(publisher.stats().cpu_ms, 0.0);
}

TEST_F(MeshPublisherTest, ARequestBringsAFullSnapshotOfEveryBlock) {
  Mapper mapper(testParams());
  MeshPublisherSettings settings;
  MeshPublisher publisher(ctx_, settings, testParams().volume);
  publisher.subscribe();
  play(mapper, publisher);
  receiveAll();
  ASSERT_EQ(full_, 0);
  rekon_msgs::mesh_request_t request{};
  request.requester = "test";
  subscriber_->publish(channel::kMeshRequest, request);
  while (ctx_.bus().handle(0)) {  // the publisher's handler runs here (a memory:// bus dispatches on handle())
  }
  const int64_t blocks_before = blocks_;
  publisher.tick(mapper);
  receiveAll();
  EXPECT_GE(full_, 1);
  EXPECT_EQ(blocks_ - blocks_before, static_cast<int64_t>(mapper.volume().blockCoords().size()));
  EXPECT_EQ(publisher.stats().full_snapshots, 1);
}

// Issue 27: a viewer counts corrections, so every block says why it changed.
// Fusion is new data; a graph update that re-integrates is a correction;
// what the final pass changes is the final pass; a correction not sent yet
// stays one when new data lands on the block before it goes out.
TEST_F(MeshPublisherTest, EveryBlockCarriesTheCauseOfItsChange) {
  Mapper mapper(testParams());
  MeshPublisherSettings settings;
  settings.rate_hz = 100;
  settings.max_bytes_per_s = 1e9;  // nothing held back: every change goes out at the next tick
  MeshPublisher publisher(ctx_, settings, testParams().volume);
  play(mapper, publisher);
  publisher.finish(mapper, BlockCause::kNewData);  // the last KF keyframe, fused
  receiveAll();
  const int64_t fused = causes_[0];
  EXPECT_GT(fused, 0);
  EXPECT_EQ(causes_[1] + causes_[2], 0);  // nothing moved: no correction

  Pose moved = Pose::Identity();
  moved.translation() = Eigen::Vector3d(0.05, 0, 0);  // DVO keyframe 0 5 cm to the side: every KF keyframe moves
  const ReintegrationRound round = mapper.applyGraphUpdate({{0, moved}});
  ASSERT_GT(round.keyframes, 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(20));  // past the 100 Hz rate
  publisher.tick(mapper, BlockCause::kCorrection);
  receiveAll();
  EXPECT_GT(causes_[1], 0);
  EXPECT_EQ(causes_[0], fused);
  EXPECT_EQ(causes_[2], 0);
  std::cout << "blocks: " << fused << " fused, " << causes_[1] << " corrected\n";
}

}  // namespace
}  // namespace rekon::mapper
