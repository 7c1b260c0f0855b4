// The viewer's state and protocol without a server: block versions, removals,
// poses through keyframes and graph updates, the binary block message and
// the PLY download.
#include <gtest/gtest.h>

#include <thread>

#include <cstring>
#include <fstream>
#include <map>
#include <tuple>
#include <sstream>

#include "rekon/common/mesh.hpp"
#include "rekon/viewer/protocol.hpp"
#include "rekon/viewer/viewer_state.hpp"
#include "test_support.hpp"
#include "viewer_test_support.hpp"

namespace rekon::viewer {
namespace {

using test::syntheticBlock;

TEST(ViewerProtocol, BlockMessageRoundTripsBitForBit) {
  BlockMesh b = syntheticBlock({3, -2, 7}, 42, 5);
  b.cause = BlockCause::kCorrection;
  const std::string bytes = encodeBlockMessage(b);
  // 36 header + 7 vertices * 12 + 21 color bytes padded to 24 + 5 triangles * 12
  EXPECT_EQ(bytes.size(), 36u + 84u + 24u + 60u);
  const auto back = decodeBlockMessage(bytes);
  ASSERT_TRUE(back);
  EXPECT_EQ(std::make_tuple(back->x, back->y, back->z), std::make_tuple(3, -2, 7));
  EXPECT_EQ(back->version, 42);
  EXPECT_EQ(back->cause, BlockCause::kCorrection);
  EXPECT_EQ(back->vertices, b.vertices);
  EXPECT_EQ(back->colors, b.colors);
  EXPECT_EQ(back->triangles, b.triangles);
}

TEST(ViewerProtocol, MalformedBlockMessagesAreRejected) {
  const std::string good = encodeBlockMessage(syntheticBlock({0, 0, 0}, 1, 4));
  EXPECT_FALSE(decodeBlockMessage(good.substr(0, 35)));               // shorter than the header
  std::string bad_cause = good;
  bad_cause[32] = 3;  // no such cause
  EXPECT_FALSE(decodeBlockMessage(bad_cause));
  EXPECT_FALSE(decodeBlockMessage(good.substr(0, good.size() - 1)));  // truncated
  EXPECT_FALSE(decodeBlockMessage(good + "x"));                        // trailing byte
  std::string bad_magic = good;
  bad_magic[0] = 'X';
  EXPECT_FALSE(decodeBlockMessage(bad_magic));
  std::string bad_index = good;
  const uint32_t huge = 1000;
  std::memcpy(bad_index.data() + bad_index.size() - 4, &huge, 4);  // an index past the block's vertices
  EXPECT_FALSE(decodeBlockMessage(bad_index));
  std::string absurd = good;
  const uint32_t n = 0xFFFFFFFF;
  std::memcpy(absurd.data() + 24, &n, 4);  // a vertex count that would overflow the size check
  EXPECT_FALSE(decodeBlockMessage(absurd));
}

// A page's report goes into /state.json as is: only the known keys with
// finite numbers survive, so nothing a client sends can break that JSON.
TEST(ViewerProtocol, ClientReportKeepsOnlyKnownFiniteNumbers) {
  EXPECT_EQ(parseClientReport(R"({"type":"report","blocks":12,"vertices":300,"latency_ms_p50":41.5})"),
            R"({"blocks":12,"vertices":300,"latency_ms_p50":41.5})");
  EXPECT_EQ(parseClientReport(R"({"type":"hello","blocks":12})"), std::nullopt);
  EXPECT_EQ(parseClientReport("not json at all"), std::nullopt);
  // Strings, objects, non-finite numbers, unknown keys and injected JSON are dropped.
  EXPECT_EQ(parseClientReport(R"({"type":"report","blocks":"12\"}],\"x\":{","vertices":1e999,"triangles":NaN,)"
                              R"("evil":5,"updates":{"a":1},"messages":-3})"),
            R"({"messages":-3})");
  EXPECT_EQ(parseClientReport(R"({"type":"report","position_sum":)"), "{}");  // cut short
}

TEST(ViewerProtocol, PlyBytesAreWhatWritePlyWrites) {
  ViewerState state;
  for (int i = 0; i < 3; ++i) state.applyBlock(syntheticBlock({i, 0, 0}, 1, 6));
  const Mesh mesh = state.mesh();
  EXPECT_EQ(mesh.vertices.size(), 3u * 8u);
  EXPECT_EQ(mesh.triangles.size(), 3u * 6u);
  rekon::test::TempDir dir;
  writePly(mesh, dir / "ref.ply");
  EXPECT_EQ(plyBytes(mesh), rekon::test::readText(dir / "ref.ply"));
  std::ofstream(dir / "served.ply", std::ios::binary) << plyBytes(mesh);
  const Mesh back = readPly(dir / "served.ply");
  EXPECT_EQ(back.vertices.size(), mesh.vertices.size());
  EXPECT_EQ(back.triangles.back(), mesh.triangles.back());  // indices offset per block
}

TEST(ViewerState, NewerVersionsReplaceOlderAreIgnoredEmptyRemoves) {
  ViewerState state;
  std::vector<Update> heard;
  state.setListener([&](const Update& u) { heard.push_back(u); });
  state.applyBlock(syntheticBlock({1, 1, 1}, 5, 10));
  state.applyBlock(syntheticBlock({1, 1, 1}, 4, 3));  // older: ignored
  EXPECT_EQ(state.counts().triangles, 10u);
  state.applyBlock(syntheticBlock({1, 1, 1}, 6, 3));
  EXPECT_EQ(state.counts().triangles, 3u);
  EXPECT_EQ(state.counts().blocks, 1u);
  BlockMesh removal;
  removal.x = removal.y = removal.z = 1;
  removal.version = 7;
  state.applyBlock(removal);
  EXPECT_EQ(state.counts().blocks, 0u);
  EXPECT_EQ(state.counts().vertices, 0u);
  state.applyBlock(syntheticBlock({1, 1, 1}, 6, 3));  // older than the removal: stays removed
  EXPECT_EQ(state.counts().blocks, 0u);
  ASSERT_EQ(heard.size(), 3u);  // v5, v6, the removal
  EXPECT_TRUE(heard[2].binary);
  EXPECT_EQ(heard[2].key, "b 1 1 1");
  EXPECT_EQ(decodeBlockMessage(*heard[2].payload)->vertices.size(), 0u);
}

// Issue 27: a block re-sent with new data is no correction; only the
// versions a graph update's re-integration (or the final pass) made count.
TEST(ViewerState, OnlyCorrectedVersionsCountAsCorrections) {
  ViewerState state;
  for (int v = 1; v <= 3; ++v) state.applyBlock(syntheticBlock({0, 0, 0}, v, 4));  // re-sent with new data
  BlockMesh corrected = syntheticBlock({0, 0, 0}, 4, 4);
  corrected.cause = BlockCause::kCorrection;
  state.applyBlock(corrected);
  state.applyBlock(corrected);  // the same version again: ignored
  BlockMesh final_pass = syntheticBlock({1, 0, 0}, 5, 4);
  final_pass.cause = BlockCause::kFinalPass;
  state.applyBlock(final_pass);
  const ViewerState::Counts c = state.counts();
  EXPECT_EQ(c.block_updates, 5u);
  EXPECT_EQ(c.block_corrections, 1u);
  EXPECT_EQ(c.final_pass_blocks, 1u);
  EXPECT_NE(state.stateJson().find(R"("block_corrections":1,"final_pass_blocks":1)"), std::string::npos);
}

// Issue 27: a block the mapper sends first as a coarse mesh (an odd time
// version, one below its change's full mesh) is held until the full mesh
// replaces it; an older coarse one never replaces a full one, and a corrected
// block counts as one correction, not two.
TEST(ViewerState, TheFullMeshReplacesTheCoarseOneAndCountsOnce) {
  ViewerState state;
  const int64_t change = 1'764'000'000'000'000;  // even: a full mesh's time version
  BlockMesh coarse = syntheticBlock({0, 0, 0}, change - 1, 2);
  coarse.cause = BlockCause::kCorrection;
  BlockMesh full = syntheticBlock({0, 0, 0}, change, 8);
  full.cause = BlockCause::kCorrection;
  ASSERT_TRUE(ViewerState::isCoarse(coarse.version));
  ASSERT_FALSE(ViewerState::isCoarse(full.version));
  ASSERT_FALSE(ViewerState::isCoarse(3));  // a test's small versions carry no time: never coarse
  state.applyBlock(coarse);
  EXPECT_EQ(state.counts().coarse_blocks, 1u);
  EXPECT_EQ(state.counts().triangles, 2u);
  EXPECT_EQ(state.counts().block_corrections, 0u);
  state.applyBlock(full);
  state.applyBlock(coarse);  // late: older than the full mesh, ignored
  const ViewerState::Counts c = state.counts();
  EXPECT_EQ(c.coarse_blocks, 0u);
  EXPECT_EQ(c.triangles, 8u);
  EXPECT_EQ(c.block_corrections, 1u);
  EXPECT_EQ(c.block_updates, 2u);
  EXPECT_NE(state.stateJson().find(R"("coarse_blocks":0)"), std::string::npos);
}

TEST(ViewerState, FullSnapshotRemovesBlocksItDoesNotName) {
  ViewerState state;
  for (int i = 0; i < 5; ++i) state.applyBlock(syntheticBlock({i, 0, 0}, 1));
  state.startFullSnapshot();
  state.applyBlocks({syntheticBlock({0, 0, 0}, 1), syntheticBlock({1, 0, 0}, 2), syntheticBlock({9, 0, 0}, 1)});
  EXPECT_EQ(state.counts().blocks, 6u);  // nothing removed before the snapshot is complete
  state.endFullSnapshot();
  EXPECT_EQ(state.counts().blocks, 3u);  // 0, 1 and 9; 2, 3 and 4 are gone
  EXPECT_EQ(state.mesh().triangles.size(), 3u * 20u);
}

TEST(ViewerState, CameraIsPlacedThroughItsKeyframeAndMovesWithGraphUpdates) {
  ViewerState state;
  std::map<std::string, std::string> last;
  state.setListener([&](const Update& u) { last[u.key] = *u.payload; });
  Pose in_kf = Pose::Identity();
  in_kf.translation() = Eigen::Vector3d(0, 0, 1);
  state.addTrackedFrame(0, 9, in_kf, false);  // keyframe 9 unknown: nothing to place
  EXPECT_EQ(state.counts().camera_frame, -1);
  Pose kf = Pose::Identity();
  kf.translation() = Eigen::Vector3d(1, 0, 0);
  state.addKeyframe(9, kf);
  state.addTrackedFrame(1, 9, in_kf, false);
  EXPECT_NE(last["camera"].find("[1.0000,0.0000,1.0000,"), std::string::npos) << last["camera"];
  kf.translation() = Eigen::Vector3d(2, 0, 0);
  state.applyGraph({{9, kf}});
  EXPECT_NE(last["camera"].find("[2.0000,0.0000,1.0000,"), std::string::npos) << last["camera"];
  EXPECT_NE(last["trajectory"].find("[2.0000,0.0000,1.0000]"), std::string::npos) << last["trajectory"];
  state.addLoopEdge(9, 3);
  EXPECT_NE(last["edges"].find("[9,3]"), std::string::npos);
}

TEST(ViewerState, SnapshotHasEveryBlockAndTheStatus) {
  ViewerState state;
  for (int i = 0; i < 40; ++i) state.applyBlock(syntheticBlock({i, 0, 0}, 1));
  state.heartbeat("mapper", 12, "host", "running", 77);
  state.stats("mapper", R"({"reintegrations": 3})");
  int blocks = 0;
  bool status = false;
  for (const Update& u : state.snapshot()) {
    blocks += u.binary;
    if (u.key == "status") status = u.payload->find(R"("last_frame":77)") != std::string::npos;
  }
  EXPECT_EQ(blocks, 40);
  EXPECT_TRUE(status);
  EXPECT_NE(state.stateJson().find(R"("blocks":40)"), std::string::npos) << state.stateJson();
}

// A service that stops sending heartbeats is shown as gone: "exited" after
// an orderly end, "silent" when it was running; a new heartbeat brings it back.
TEST(ViewerState, ServicesWithoutHeartbeatsAreMarkedExitedOrSilent) {
  ViewerState state;
  state.heartbeat("mapper", 12, "host", "finishing", 999);
  state.heartbeat("tracker", 13, "host", "running", 500);
  state.stats("optimiser", R"({"keyframes": 3})");  // stats without a heartbeat: nothing to mark
  state.markSilent(10.0);
  EXPECT_NE(state.stateJson().find(R"("state":"finishing")"), std::string::npos);
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  state.markSilent(0.01);
  const std::string json = state.stateJson();
  EXPECT_NE(json.find(R"("mapper":{"pid":12,"host":"host","state":"exited")"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("tracker":{"pid":13,"host":"host","state":"silent")"), std::string::npos) << json;
  state.heartbeat("tracker", 14, "host", "running", 0);
  EXPECT_NE(state.stateJson().find(R"("tracker":{"pid":14,"host":"host","state":"running")"), std::string::npos);
}

// A service killed and restarted (issue 48) shows its restarts; a late
// heartbeat of the instance it replaced changes nothing.
TEST(ViewerState, ARestartedServiceShowsItsRestartsAndItsOldInstanceIsIgnored) {
  ViewerState state;
  state.heartbeat("tracker", 13, "host", "running", 500);
  EXPECT_NE(state.stateJson().find(R"("frames_per_s":0.0,"restarts":0,)"), std::string::npos) << state.stateJson();
  state.heartbeat("tracker", 14, "host", "starting", -1);
  state.heartbeat("tracker", 13, "host", "running", 501);  // the killed one's, still on the wire
  std::string json = state.stateJson();
  EXPECT_NE(json.find(R"("tracker":{"pid":14,"host":"host","state":"starting","last_frame":-1)"), std::string::npos)
      << json;
  EXPECT_NE(json.find(R"("restarts":1,)"), std::string::npos) << json;
  state.heartbeat("tracker", 15, "host", "running", 520);
  EXPECT_NE(state.stateJson().find(R"("restarts":2,)"), std::string::npos) << state.stateJson();
}

}  // namespace
}  // namespace rekon::viewer
