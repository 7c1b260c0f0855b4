// rekon-mapper as a process, fed by this test over a real bus: every frame is
// sent again while the mapper waits for its tracked frame, and again after it
// was joined, as the player does when acknowledgements stall for a second.
// Before the fix the mapper counted each copy as one more queued frame (the
// count drifted up by one per copy), held back every acknowledgement from then
// on and the player stalled for good (long runs near frame 8 700); and a copy
// of a fused frame was later counted as dropped.
#include <gtest/gtest.h>

#include <chrono>
#include <mutex>
#include <set>
#include <thread>

#include "rekon/common/bus.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/synth/synth.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"
#include "test_support.hpp"

namespace rekon {
namespace {

using Clock = std::chrono::steady_clock;
constexpr int kFrames = 16;
constexpr int kCopiesWhileWaiting = 2;  // sent again before the tracked frame comes
constexpr int kCopiesAfterJoin = 1;     // sent again after it was joined (in the work or fused)

long long jsonInt(const std::string& json, const std::string& key) {
  const auto at = json.find("\"" + key + "\":");
  if (at == std::string::npos) return -1;
  return std::stoll(json.substr(at + key.size() + 3));
}

TEST(MapperResend, FramesSentAgainAreNeitherQueuedTwiceNorDroppedAndEveryFrameIsAcknowledged) {
  if (!test::insideNetns()) return;
  test::TempDir dir;
  synth::SequenceOptions sequence;
  sequence.scene = "room";
  sequence.frames = kFrames;
  synth::writeSequence(sequence, dir / "room");
  const TumDataset data(dir / "room");

  Bus bus(BusOptions{});
  std::mutex mutex;
  std::set<int64_t> acked;
  int64_t acks = 0;
  bool running = false;
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t& m) {
    if (m.service == "mapper" && m.state == "running") running = true;
  });
  bus.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const rekon_msgs::frame_ack_t& m) {
    std::lock_guard<std::mutex> lock(mutex);
    if (m.service != "mapper") return;
    acked.insert(m.frame_id);
    ++acks;
  });
  // max_queued_frames 2: the old count exceeded it after the first copies; the
  // short progress interval runs the progress log (the worker's counters read
  // from another thread) many times, under TSan too.
  const pid_t mapper = test::spawnShell(
      "exec timeout -k 5 200 " + test::binDir() + "/rekon-mapper --out " + (dir / "out") +
      " --set mapper.max_queued_frames=2 --set mapper.kappa=4 --set mapper.wait_for_optimiser=false"
      " --set mapper.use_store=false --set mapper.write_uncorrected_mesh=false --set mapper.progress_interval_s=0.02 > " +
      (dir / "mapper.log") + " 2>&1");
  ASSERT_GT(mapper, 0);
  const auto spinFor = [&](double seconds) {
    const auto end = Clock::now() + std::chrono::duration<double>(seconds);
    while (Clock::now() < end) bus.handle(5);
  };
  const auto deadline = Clock::now() + std::chrono::seconds(60);
  while (!running && Clock::now() < deadline) bus.handle(20);
  ASSERT_TRUE(running) << test::readText(dir / "mapper.log");

  FrameSender sender(bus, TransportMode::kLcm, "", FrameRingLayout{});
  const Trajectory& gt = data.groundTruth();
  rekon_msgs::keyframe_t kf{};
  kf.keyframe_id = 0;
  kf.frame_id = 0;
  kf.timestamp = data.timestamp(0);
  kf.pose_world = toMsg(gt.front().pose);
  bus.publish(channel::kKeyframes, kf);
  for (int i = 0; i < kFrames; ++i) {
    const EncodedFrame encoded = data.loadEncoded(static_cast<size_t>(i));
    const RgbdFrame frame = data.decode(static_cast<size_t>(i), encoded);
    for (int copy = 0; copy <= kCopiesWhileWaiting; ++copy) {
      sender.send(frame, data.intrinsics(), &encoded);
      spinFor(0.02);
    }
    rekon_msgs::tracked_frame_t t{};
    t.frame_id = i;
    t.timestamp = data.timestamp(static_cast<size_t>(i));
    t.keyframe_id = 0;
    t.pose_in_keyframe = toMsg(gt.front().pose.inverse() * gt[static_cast<size_t>(i)].pose);
    bus.publish(channel::kTrackedFrames, t);
    spinFor(0.05);
    for (int copy = 0; copy < kCopiesAfterJoin; ++copy) {
      sender.send(frame, data.intrinsics(), &encoded);
      spinFor(0.02);
    }
  }
  // Every frame acknowledged once the mapper caught up (the stall left the
  // acknowledgements held back for good).
  const auto ack_deadline = Clock::now() + std::chrono::seconds(60);
  while (Clock::now() < ack_deadline) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (acked.size() == static_cast<size_t>(kFrames)) break;
    }
    bus.handle(20);
  }
  {
    std::lock_guard<std::mutex> lock(mutex);
    EXPECT_EQ(acked.size(), static_cast<size_t>(kFrames)) << test::readText(dir / "mapper.log");
  }
  rekon_msgs::end_of_stream_t end{};
  end.last_frame_id = kFrames - 1;
  end.frames = kFrames;
  for (int i = 0; i < 3; ++i) bus.publish(channel::kEndOfStream, end), spinFor(0.05);
  const int status = test::waitForExit(mapper, 90);
  const std::string log = test::readText(dir / "mapper.log");
  ASSERT_EQ(status, 0) << log;

  // Each frame counted once: all fused, none dropped, every copy seen as one.
  const std::string stats = test::readText(dir / "out/mapper_stats.json");
  EXPECT_EQ(jsonInt(stats, "frames_fused"), kFrames) << stats;
  EXPECT_EQ(jsonInt(stats, "frames_dropped"), 0) << stats;
  EXPECT_EQ(jsonInt(stats, "frames_received_again"), kFrames * (kCopiesWhileWaiting + kCopiesAfterJoin)) << stats;
  EXPECT_EQ(jsonInt(stats, "kf_keyframes"), kFrames / 4) << stats;
  EXPECT_NE(log.find("frames fused into"), std::string::npos) << "the progress log never ran:\n" << log;
  EXPECT_EQ(test::crashLines(log), "");
}

}  // namespace
}  // namespace rekon
