// Frames cross process boundaries unchanged: a player and a listener in a
// private network namespace, through the shared-memory ring and inline LCM,
// recorded by lcm-logger, and driven by `rekon run`.
#include <gtest/gtest.h>
#include <lcm/eventlog.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "rekon/common/bus.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using rekon::test::runCommand;

namespace {

using rekon::test::inNetns;
std::string rekonBin() { return rekon::test::binDir() + "/rekon"; }
std::string playerBin() { return rekon::test::binDir() + "/rekon-player"; }

// "frame_id timestamp hash" lines of the first n frames, decoded in this process.
std::vector<std::string> expectedLines(const std::string& dataset, int n) {
  rekon::DatasetOptions o;
  o.max_frames = n;
  rekon::TumDataset ds(dataset, o);
  std::vector<std::string> lines;
  for (size_t i = 0; i < ds.size(); ++i) {
    const auto f = ds.load(i);
    char line[96];
    std::snprintf(line, sizeof(line), "%ld %.6f %016lx", static_cast<long>(f.id), f.timestamp,
                  static_cast<unsigned long>(rekon::frameHash(f)));
    lines.push_back(line);
  }
  return lines;
}

std::vector<std::string> readLines(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  return lines;
}

// Plays `frames` frames to a listener in a fresh namespace; returns the listener's lines.
std::vector<std::string> playToListener(const std::string& dataset, int frames, const std::string& mode,
                                        const rekon::test::TempDir& dir, const std::string& extra = "",
                                        const std::string& player_args = "") {
  const std::string script =
      "timeout 120 " + rekonBin() + " listen --frames-out " + (dir / "frames.txt") + " > " + (dir / "listener.log") + " 2>&1 & listener=$!; " +
      "timeout 120 " + playerBin() + " --dataset " + dataset + " --set player.max_frames=" + std::to_string(frames) +
      " --set player.wait_for=[listener] --set transport.mode=" + mode + " --set transport.segment=rekon_test_" +
      std::to_string(getpid()) + " " + player_args + " > " + (dir / "player.log") + " 2>&1; status=$?; [ $status -eq 0 ] || kill $listener; wait $listener; exit $status";
  std::string out;
  const int rc = runCommand(inNetns() + " bash -c '" + extra + script + "'", &out);
  auto logOf = [&](const std::string& name) {
    std::ifstream in(dir / name);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  };
  EXPECT_EQ(rc, 0) << out << "\nplayer log:\n" << logOf("player.log") << "\nlistener log:\n" << logOf("listener.log");
  return readLines(dir / "frames.txt");
}

}  // namespace

TEST(MultiProcess, HundredFramesArriveBitExactThroughSharedMemory) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  rekon::test::TempDir dir;
  EXPECT_EQ(playToListener(data, 100, "shm", dir), expectedLines(data, 100));
}

// Decoded ahead on two threads (player.decode_threads): the same frames, in order.
TEST(MultiProcess, FramesDecodedAheadArriveBitExactAndInOrder) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  rekon::test::TempDir dir;
  EXPECT_EQ(playToListener(data, 100, "shm", dir, "", "--set player.decode_threads=2"), expectedLines(data, 100));
}

TEST(MultiProcess, HundredFramesArriveBitExactThroughInlineLcm) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  rekon::test::TempDir dir;
  EXPECT_EQ(playToListener(data, 100, "lcm", dir), expectedLines(data, 100));
}

TEST(MultiProcess, LcmLoggerRecordsARunThatDecodesFrameByFrame) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  rekon::test::TempDir dir;
  const std::string log = dir / "run.lcmlog";
  // lcm-logger acknowledges nothing, so the player paces itself to real time
  // (--rate 1) and the logger gets a large socket buffer: a loaded machine
  // must not make it drop a 0.5 MB inline frame.
  const std::string logger = "lcm-logger --quiet --lcm-url=udpm://239.255.76.67:7667?ttl=0\\&recv_buf_size=4194304 " + log +
                             " > /dev/null 2>&1 & logger=$!; sleep 0.3; trap \"kill -INT $logger; wait $logger\" EXIT; ";
  const auto lines = playToListener(data, 20, "lcm", dir, logger, "--rate 1");
  ASSERT_EQ(lines.size(), 20u);

  lcm_eventlog_t* ev = lcm_eventlog_create(log.c_str(), "r");
  ASSERT_NE(ev, nullptr) << "lcm-logger wrote no log at " << log;
  rekon::FrameReceiver receiver;
  std::vector<std::string> decoded;
  int other_channels = 0;
  while (lcm_eventlog_event_t* e = lcm_eventlog_read_next_event(ev)) {
    if (std::string(e->channel) == "REKON_FRAMES") {
      rekon_msgs::frame_t msg;
      std::string why;
      ASSERT_TRUE(rekon::decodeMessage(e->data, e->datalen, &msg, &why)) << why;
      const auto f = receiver.receive(msg, nullptr);
      ASSERT_TRUE(f.has_value());
      char line[96];
      std::snprintf(line, sizeof(line), "%ld %.6f %016lx", static_cast<long>(f->id), f->timestamp,
                    static_cast<unsigned long>(rekon::frameHash(*f)));
      decoded.push_back(line);
    } else {
      ++other_channels;
    }
    lcm_eventlog_free_event(e);
  }
  lcm_eventlog_destroy(ev);
  EXPECT_EQ(decoded, expectedLines(data, 20));
  EXPECT_GT(other_channels, 0) << "heartbeats and acknowledgements should be in the log too";
}

TEST(MultiProcess, RunWritesStatsAndLeavesNoSharedMemory) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  rekon::test::TempDir dir;
  std::string out;
  const int rc = runCommand(inNetns() + " " + rekonBin() + " run --dataset " + data + " --out " + (dir / "out") +
                                " --set player.max_frames=30 --set run.services=[player]",
                            &out);
  ASSERT_EQ(rc, 0) << out;
  std::ifstream stats(dir / "out/stats.json");
  std::stringstream s;
  s << stats.rdbuf();
  EXPECT_NE(s.str().find("\"frames\": 30"), std::string::npos) << s.str();
  EXPECT_NE(s.str().find("\"realtime_factor\""), std::string::npos) << s.str();
  // This run's segments only: other runs on the machine have their own.
  std::ifstream config(dir / "out/config.yaml");
  int segments = 0;
  for (std::string line; std::getline(config, line);) {
    const auto colon = line.find(':');
    if (colon == std::string::npos) continue;
    std::string key = line.substr(0, colon);
    key.erase(0, key.find_first_not_of(' '));
    if (key != "segment" && key != "store_segment") continue;
    std::string name = line.substr(colon + 1);
    name.erase(0, name.find_first_not_of(" \""));
    name.erase(name.find_last_not_of(" \"") + 1);
    ++segments;
    EXPECT_FALSE(fs::exists("/dev/shm/" + name)) << "left behind: /dev/shm/" << name;
  }
  EXPECT_EQ(segments, 2) << "the frame ring's and the keyframe store's names should be in config.yaml";
}

std::string readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Issue 9 part 5: a recorded run replays into fresh services with the same
// result (log_replay.sh). For the same frames in the same order the pipeline
// is deterministic: on the 60-frame room (no loop closure) the replayed
// trajectory and meshes were byte-identical to the live ones in 4 runs of
// this test (and on 120 frames by hand), so identity is what is checked.
// There no keyframe moves (0 re-integrations; mesh.ply is mesh_uncorrected.ply):
// with loop closures, graph-update timing makes runs differ (README, Faults).
TEST(MultiProcess, LoggedRunReplaysIntoFreshServicesWithTheSameTrajectoryAndMesh) {
  rekon::test::TempDir dir;
  const std::string data = dir / "room";
  std::string out;
  // 60 frames: 3 KF keyframes, enough for a graph and a store, small for CI.
  ASSERT_EQ(runCommand("timeout 120 " + rekonBin() + " synth --scene room --frames 60 --out " + data, &out), 0) << out;
  const int rc = runCommand(inNetns() + " " + rekon::test::sourceDir() + "/tests/transport/log_replay.sh " +
                                rekon::test::binDir() + " " + data + " " + dir.path(),
                            &out);
  ASSERT_EQ(rc, 0) << out;
  ASSERT_GT(fs::file_size(dir / "run.lcmlog"), 10u << 20) << "the log should hold 60 inline frames";

  const auto poses = readLines(dir / "live/trajectory.txt");
  EXPECT_EQ(std::count_if(poses.begin(), poses.end(), [](const std::string& l) { return !l.empty() && l[0] != '#'; }), 60);
  // sensor/: the sensor channels into fresh tracker, optimiser, mapper. graph/: the pose and graph
  // channels into a mapper resuming from a keyframe store.
  for (const std::string file : {"sensor/trajectory.txt", "sensor/mesh.ply", "sensor/mesh_uncorrected.ply", "graph/mesh.ply",
                                 "graph/mesh_uncorrected.ply"}) {
    const std::string live_file = dir / ("live/" + file.substr(file.find('/') + 1)), replayed_file = dir / file;
    const std::string live = readBytes(live_file), replayed = readBytes(replayed_file);
    EXPECT_FALSE(live.empty()) << live_file;
    if (live == replayed) continue;
    // How far apart, to tell a reordering from a different result.
    std::string how;
    if (file.ends_with(".txt"))
      runCommand(rekonBin() + " eval traj " + live_file + " " + replayed_file, &how);
    else
      runCommand(rekonBin() + " eval surface " + replayed_file + " " + live_file, &how);
    ADD_FAILURE() << file << " differs from the live run's (" << replayed.size() << " vs " << live.size()
                  << " bytes):\n" << how;
  }
  // The logged map on the bus reproduces mesh.ply: the same triangles, vertices within the
  // quantisation step (voxel/1024: 10 um).
  const rekon::Mesh live_mesh = rekon::readPly(dir / "live/mesh.ply"), logged_mesh = rekon::readPly(dir / "mesh/mesh.ply");
  EXPECT_EQ(logged_mesh.triangles.size(), live_mesh.triangles.size());
  // mesh.ply's coincident vertices (a voxel at distance exactly 0) count once in the assembled
  // mesh: 147077 against 147344 measured (-0.18 %); test_mesh_on_bus checks them one by one.
  EXPECT_LE(logged_mesh.vertices.size(), live_mesh.vertices.size());
  EXPECT_GE(logged_mesh.vertices.size(), 0.99 * static_cast<double>(live_mesh.vertices.size()));
  std::string corr;
  runCommand(rekonBin() + " eval surface " + (dir / "mesh/mesh.ply") + " " + (dir / "live/mesh.ply"), &corr);
  const double corr_m = rekon::test::valueAfter(corr, "corr_m");
  EXPECT_GE(corr_m, 0.0) << corr;
  EXPECT_LT(corr_m, 1e-4) << corr;
  // The resumed mapper rebuilt the volume from the store: it fused no frame itself.
  std::ifstream graph_log(dir / "graph/mapper.log");
  std::stringstream g;
  g << graph_log.rdbuf();
  EXPECT_NE(g.str().find("the volume is rebuilt from them"), std::string::npos) << g.str();
}

TEST(MultiProcess, MissingDatasetFailsWithOneClearLine) {
  rekon::test::TempDir dir;
  std::string out;
  const int rc = runCommand(playerBin() + " --dataset " + (dir / "nope") + " --set player.wait_for=[]", &out);
  EXPECT_NE(rc, 0);
  EXPECT_NE(out.find("dataset folder not found"), std::string::npos) << out;
}
