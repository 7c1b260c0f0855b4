// The viewer's bus wiring over a memory:// bus: what the run publishes lands
// in the state (mesh blocks through the codec, full snapshots, keyframes,
// tracked frames, loop closures, heartbeats), the mapper is asked for its
// mesh at start and when a new instance is past "starting", and a message that does not
// decode is dropped without touching the state.
#include <gtest/gtest.h>

#include "inbox.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/mesh_request_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"
#include "viewer_test_support.hpp"

namespace rekon::viewer {
namespace {

struct Wiring {
  Wiring() {
    BusOptions o;
    o.url = "memory://viewer_inbox";
    viewer_bus = makeBus(o);
    run_bus = makeBus(o);
    run_bus->subscribe<rekon_msgs::mesh_request_t>(channel::kMeshRequest, [this](const rekon_msgs::mesh_request_t& m) {
      ++requests;
      EXPECT_EQ(m.requester, "viewer");
    });
    subscribeViewer(*viewer_bus, state, "viewer");
  }
  void deliver() {
    while (viewer_bus->handle(0) || run_bus->handle(0)) {
    }
  }
  // Returns the number of messages (parts).
  size_t publishMesh(const std::vector<BlockMesh>& blocks, int64_t sequence, bool full, size_t max_message_bytes) {
    MeshBlocksParams p;
    p.max_message_bytes = max_message_bytes;
    const auto messages = encodeMeshBlocks(blocks, p, sequence, full);
    for (const auto& m : messages) run_bus->publish(channel::kMeshBlocks, m);
    return messages.size();
  }
  ViewerState state;
  std::unique_ptr<Bus> viewer_bus, run_bus;
  int requests = 0;
};

std::vector<BlockMesh> row(int n, int64_t version) {
  std::vector<BlockMesh> blocks;
  for (int i = 0; i < n; ++i) blocks.push_back(test::syntheticBlock({i, 0, 0}, version, 20));
  return blocks;
}

TEST(ViewerInbox, MeshBlocksFromTheBusReachTheStateAndFullSnapshotsPrune) {
  Wiring w;
  w.deliver();
  EXPECT_EQ(w.requests, 1);  // at start
  w.publishMesh(row(30, 1), 1, false, 256 * 1024);
  w.deliver();
  EXPECT_EQ(w.state.counts().blocks, 30u);
  EXPECT_EQ(w.state.counts().triangles, 30u * 20u);
  // A full snapshot of 10 blocks in several parts (1 KB each): the other 20 are gone once it is complete.
  EXPECT_GT(w.publishMesh(row(10, 2), 2, true, 1024), 1u);
  w.deliver();
  EXPECT_EQ(w.state.counts().blocks, 10u);
  // Garbage where the compressed payload should be: dropped with a line, the state unchanged.
  rekon_msgs::mesh_blocks_t bad = encodeMeshBlocks(row(1, 9), MeshBlocksParams{}, 3, false).front();
  for (auto& byte : bad.payload) byte = static_cast<uint8_t>(byte ^ 0x5A);
  w.run_bus->publish(channel::kMeshBlocks, bad);
  w.deliver();
  EXPECT_EQ(w.state.counts().blocks, 10u);
  EXPECT_EQ(w.state.counts().block_updates, 30u + 10u + 20u);  // the first row, the snapshot, its removals
}

TEST(ViewerInbox, PosesLoopClosuresAndANewMapperInstance) {
  Wiring w;
  rekon_msgs::keyframe_t kf{};
  kf.keyframe_id = 4;
  kf.pose_world = toMsg(Pose::Identity());
  w.run_bus->publish(channel::kKeyframes, kf);
  rekon_msgs::tracked_frame_t tf{};
  tf.frame_id = 17;
  tf.keyframe_id = 4;
  tf.pose_in_keyframe = toMsg(Pose::Identity());
  w.run_bus->publish(channel::kTrackedFrames, tf);
  rekon_msgs::constraint_t loop{};
  loop.kind = rekon_msgs::constraint_t::KIND_LOOP;
  loop.from_id = 4;
  loop.to_id = 0;
  loop.relative = toMsg(Pose::Identity());
  w.run_bus->publish(channel::kConstraints, loop);
  loop.kind = rekon_msgs::constraint_t::KIND_ODOMETRY;  // not drawn
  w.run_bus->publish(channel::kConstraints, loop);
  rekon_msgs::heartbeat_t hb{};
  hb.service = "mapper";
  hb.pid = 100;
  hb.state = "running";
  w.run_bus->publish(channel::kHeartbeat, hb);
  w.run_bus->publish(channel::kHeartbeat, hb);  // the same instance: no second request
  hb.pid = 101;                                  // restarted, and not subscribed yet: an ask would be lost
  hb.state = "starting";
  w.run_bus->publish(channel::kHeartbeat, hb);
  w.deliver();
  EXPECT_EQ(w.requests, 2);  // at start, mapper 100
  hb.state = "running";  // its heartbeat as soon as it has subscribed
  w.run_bus->publish(channel::kHeartbeat, hb);
  w.deliver();
  const ViewerState::Counts c = w.state.counts();
  EXPECT_EQ(c.keyframes, 1u);
  EXPECT_EQ(c.camera_frame, 17);
  EXPECT_EQ(c.loop_edges, 1u);
  EXPECT_EQ(w.requests, 3);  // at start, mapper 100, mapper 101
  EXPECT_NE(w.state.stateJson().find(R"("mapper":{"pid":101)"), std::string::npos) << w.state.stateJson();
}

}  // namespace
}  // namespace rekon::viewer
