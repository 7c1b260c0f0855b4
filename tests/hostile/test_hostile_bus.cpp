// Live services under hostile bus traffic: rekon-tracker, rekon-optimiser and
// rekon-mapper are running when this test publishes messages that do not
// decode (wrong fingerprint, truncated, absurd array length, unknown schema
// version) and messages that decode but must not be used (NaN/infinite poses
// and intrinsics, shared-memory references out of range, stale or to a missing
// segment, corrupt, truncated, wrong-depth or wrong-size inline images). Then a
// valid sequence plays: every service must still process exactly its frames,
// count each undecodable message once, and end normally.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <thread>

#include "rekon/common/bus.hpp"
#include "rekon/common/frame_ring.hpp"
#include "rekon/common/image_io.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/synth/synth.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"
#include "test_support.hpp"


namespace rekon {
namespace {

using Clock = std::chrono::steady_clock;
// The valid sequence played after the attack: frames kFirstValid.. of a
// synthetic room. The hostile frames take the ids below kFirstValid because a
// service treats an id it has seen (even in a frame it rejected) as handled.
constexpr int kFirstValid = 13, kFrames = 12;
constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

using test::readText;
using test::spawnShell;
using test::waitForExit;

int countOf(const std::string& text, const std::string& needle) {
  int n = 0;
  for (size_t at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1)) ++n;
  return n;
}

template <class Msg>
std::string encode(Msg msg, int32_t schema_version = kSchemaVersion) {
  msg.schema_version = schema_version;
  std::string buf(static_cast<size_t>(msg.getEncodedSize()), '\0');
  msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
  return buf;
}

rekon_msgs::frame_t inlineFrame(int64_t id, const cv::Mat& depth, const std::vector<uint8_t>& color, const std::string& format) {
  rekon_msgs::frame_t f{};
  f.frame_id = id;
  f.timestamp = static_cast<double>(id) / 30;
  Intrinsics k;
  k.width = 640;
  k.height = 480;
  setIntrinsics(k, &f);
  f.shm_slot = -1;
  f.depth_png = encodePng(depth);
  f.depth_png_size = static_cast<int32_t>(f.depth_png.size());
  f.color_format = format;
  f.color = color;
  f.color_size = static_cast<int32_t>(f.color.size());
  return f;
}

TEST(HostileBus, ServicesDropEveryHostileMessageAndThenMapAValidSequence) {
  if (!test::insideNetns()) return;
  test::TempDir dir;
  synth::SequenceOptions sequence;
  sequence.scene = "room";
  sequence.frames = kFirstValid + kFrames;
  synth::writeSequence(sequence, dir / "room");

  LcmBus bus(BusOptions{});
  std::set<std::string> running;
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t& m) {
    if (m.state == "running") running.insert(m.service);
  });
  std::map<std::string, pid_t> services;
  // Whatever fails below, no service outlives the test.
  struct KillOnExit {
    std::map<std::string, pid_t>* pids;
    ~KillOnExit() {
      for (const auto& [name, pid] : *pids) {
        if (pid > 0 && waitpid(pid, nullptr, WNOHANG) == 0) waitForExit(pid, 0);
      }
    }
  } kill_on_exit{&services};
  const std::string segments = test::ownSegments("hostile");
  for (const char* s : {"tracker", "optimiser", "mapper"}) {
    services[s] = spawnShell("exec timeout -k 5 200 " + test::binDir() + "/rekon-" + s + " --out " + (dir / "out") +
                             segments + " > " + (dir / (std::string(s) + ".log")) + " 2>&1");
    ASSERT_GT(services[s], 0);
  }
  // "running" is announced after a service has subscribed to its inputs.
  const auto deadline = Clock::now() + std::chrono::seconds(60);
  while (running.size() < 3 && Clock::now() < deadline) bus.handle(20);
  ASSERT_EQ(running.size(), 3u) << readText(dir / "tracker.log") << readText(dir / "mapper.log");

  // Paced, so no socket buffer overflows on a loaded machine and every count below is exact.
  const auto publishRaw = [&](const char* channel_name, const std::string& bytes) {
    bus.publishRaw(channel_name, bytes.data(), static_cast<int>(bytes.size()));
    bus.handle(1);
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  };

  // 1. Messages that do not decode: the same four on each of five channels.
  cv::Mat depth(480, 640, CV_16UC1, cv::Scalar(3000));
  cv::Mat color(480, 640, CV_8UC3, cv::Scalar(40, 80, 120));
  const std::string frame_bytes = encode(inlineFrame(900, depth, encodePng(color), "png"));
  rekon_msgs::graph_update_t graph{};
  graph.version = 1;
  graph.num_keyframes = 1;
  graph.keyframe_ids = {0};
  graph.poses = {toMsg(Pose::Identity())};
  std::string absurd = encode(graph);
  // num_keyframes sits after the 8-byte fingerprint, schema_version and version.
  absurd[20] = '\x7f', absurd[21] = absurd[22] = absurd[23] = '\xff';
  const std::vector<std::string> undecodable = {
      std::string(64, '\x5a'),                                  // wrong fingerprint
      frame_bytes.substr(0, frame_bytes.size() / 2),            // truncated
      absurd,                                                   // array length 2^31-1
      encode(graph, kSchemaVersion + 41),                       // unknown schema version
  };
  const char* channels[] = {channel::kFrames,       channel::kTrackedFrames, channel::kKeyframes,
                            channel::kConstraints,  channel::kGraphUpdates,  channel::kMeshRequest};
  for (const char* c : channels)
    for (const auto& bytes : undecodable) publishRaw(c, bytes);

  // 2. Frames that decode but must be dropped by the frame receiver.
  std::vector<rekon_msgs::frame_t> bad_frames;
  auto nan_fx = inlineFrame(0, depth, encodePng(color), "png");
  nan_fx.fx = kNan;
  auto inf_scale = inlineFrame(1, depth, encodePng(color), "png");
  inf_scale.depth_scale = kInf;
  auto negative = inlineFrame(2, depth, encodePng(color), "png");
  negative.width = -640;
  auto huge = inlineFrame(3, depth, encodePng(color), "png");
  huge.width = huge.height = 100000;
  auto garbage = inlineFrame(4, depth, encodePng(color), "png");
  garbage.depth_png.assign(5000, 0x42);
  garbage.depth_png_size = 5000;
  auto jpeg = encodeJpeg(color);
  jpeg.resize(jpeg.size() / 2);
  auto truncated_jpeg = inlineFrame(5, depth, jpeg, "jpeg");
  auto eight_bit = inlineFrame(6, cv::Mat(480, 640, CV_8UC1, cv::Scalar(9)), encodePng(color), "png");
  auto small_color = inlineFrame(7, depth, encodePng(cv::Mat(240, 320, CV_8UC3, cv::Scalar(1, 2, 3))), "png");
  bad_frames = {nan_fx, inf_scale, negative, huge, garbage, truncated_jpeg, eight_bit, small_color};
  // Shared-memory references: a missing segment, and a real ring whose slot 0
  // holds a frame, referenced out of range, with a stale and with an odd generation.
  const std::string segment = "rekon_hostile_" + std::to_string(getpid());
  FrameRingWriter ring(segment, FrameRingLayout{4, 640, 480});
  RgbdFrame written;
  written.id = 8;
  written.depth = depth;
  written.color = color;
  const uint64_t stale_generation = ring.write(0, written);
  const uint64_t generation = ring.write(0, written);  // slot 0 overwritten: stale_generation is gone
  auto shm = inlineFrame(8, depth, {}, "");
  shm.depth_png.clear();
  shm.depth_png_size = 0;
  shm.color_size = 0;
  shm.shm_segment = segment;
  auto missing = shm;  // frame 8
  missing.shm_segment = segment + "_missing";
  missing.shm_slot = 0;
  missing.shm_generation = static_cast<int64_t>(generation);
  auto out_of_range = shm;
  out_of_range.frame_id = 9;
  out_of_range.shm_slot = 4;
  out_of_range.shm_generation = static_cast<int64_t>(generation);
  auto negative_slot = shm;
  negative_slot.frame_id = 10;
  negative_slot.shm_slot = -3;
  negative_slot.shm_generation = static_cast<int64_t>(generation);
  auto stale = shm;
  stale.frame_id = 11;
  stale.shm_slot = 0;
  stale.shm_generation = static_cast<int64_t>(stale_generation);
  auto odd = shm;
  odd.frame_id = 12;
  odd.shm_slot = 0;
  odd.shm_generation = static_cast<int64_t>(generation) + 1;
  for (const auto& f : {missing, out_of_range, negative_slot, stale, odd}) bad_frames.push_back(f);
  for (const auto& f : bad_frames) publishRaw(channel::kFrames, encode(f));

  // 3. Poses and information that decode but are not finite.
  rekon_msgs::pose_t nan_pose = toMsg(Pose::Identity());
  nan_pose.t[1] = kNan;
  rekon_msgs::pose_t inf_pose = toMsg(Pose::Identity());
  inf_pose.q[3] = kInf;
  rekon_msgs::tracked_frame_t tracked{};
  tracked.frame_id = 5;
  tracked.pose_in_keyframe = nan_pose;
  publishRaw(channel::kTrackedFrames, encode(tracked));
  rekon_msgs::keyframe_t keyframe{};
  keyframe.keyframe_id = 6;
  keyframe.frame_id = 6;
  keyframe.pose_world = inf_pose;
  publishRaw(channel::kKeyframes, encode(keyframe));
  rekon_msgs::constraint_t constraint{};
  constraint.from_id = 6;
  constraint.to_id = 0;
  constraint.relative = toMsg(Pose::Identity());
  for (double& v : constraint.information) v = kNan;
  publishRaw(channel::kConstraints, encode(constraint));
  graph.poses = {nan_pose};
  graph.version = 1000;
  publishRaw(channel::kGraphUpdates, encode(graph));

  // 4. A valid sequence: every frame of it, and nothing else, must come through.
  const int player_status = waitForExit(
      // Paced by time, not acknowledgements: the player would wait for acks of
  // frames before first_frame that it never sent (rate max). A tenth of the
  // recorded rate leaves each service 0.3 s per frame on a loaded machine.
      spawnShell("exec " + test::binDir() + "/rekon-player --dataset " + (dir / "room") + " --rate 0.1 --set player.first_frame=" +
            std::to_string(kFirstValid) + segments + " > " + (dir / "player.log") + " 2>&1"),
      120);
  EXPECT_EQ(player_status, 0) << readText(dir / "player.log");
  for (const auto& [name, pid] : services) {
    EXPECT_EQ(waitForExit(pid, 150), 0) << "rekon-" << name << ":\n" << readText(dir / (name + ".log"));
  }

  // Undecodable messages are counted by every service subscribed to the channel:
  // tracker FRAMES + GRAPH_UPDATES, optimiser TRACKED_FRAMES + KEYFRAMES +
  // CONSTRAINTS, mapper FRAMES + TRACKED_FRAMES + KEYFRAMES + GRAPH_UPDATES + MESH_REQUEST.
  const int per_channel = static_cast<int>(undecodable.size());
  const std::map<std::string, int> malformed = {{"tracker", 2 * per_channel}, {"optimiser", 3 * per_channel}, {"mapper", 5 * per_channel}};
  for (const auto& [name, expected] : malformed) {
    const std::string stats = readText(dir / ("out/" + name + "_stats.json"));
    EXPECT_NE(stats.find("\"malformed_messages\": " + std::to_string(expected)), std::string::npos) << name << ": " << stats;
    const std::string log = readText(dir / (name + ".log"));
    EXPECT_EQ(test::crashLines(log), "") << name;
  }
  // Each bad frame is one warning in each frame reader, and none became a frame.
  for (const char* reader : {"tracker", "mapper"}) {
    const std::string log = readText(dir / (std::string(reader) + ".log"));
    EXPECT_EQ(countOf(log, "dropped:"), static_cast<int>(bad_frames.size())) << reader << ":\n" << log;
  }
  EXPECT_EQ(readTumTrajectory(dir / "out/odometry.txt").size(), static_cast<size_t>(kFrames));
  EXPECT_EQ(readTumTrajectory(dir / "out/trajectory.txt").size(), static_cast<size_t>(kFrames));
  EXPECT_TRUE(std::filesystem::file_size(dir / "out/mesh.ply") > 1000);
}

}  // namespace
}  // namespace rekon
