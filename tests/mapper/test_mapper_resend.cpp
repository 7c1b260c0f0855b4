// The mapper service's logic in-process, fed by this test over a memory://
// bus (no socket, no network namespace; under ASan and TSan in CI): every
// frame is sent again while the mapper waits for its tracked frame, and again
// after it was joined, as the player does when acknowledgements stall.
// Before the fix the mapper counted each copy as one more queued frame (the
// count drifted up by one per copy), held back every acknowledgement from then
// on and the player stalled for good (long runs near frame 8 700); and a copy
// of a fused frame was later counted as dropped.
#include <gtest/gtest.h>

#include <unistd.h>

#include <chrono>
#include <functional>
#include <set>
#include <string>
#include <thread>

#include "mapper_service.hpp"
#include "rekon/mapper/store/keyframe_store.hpp"
#include "rekon/common/bus.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/service.hpp"
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

// The mapper service on a thread of this process; stopped and joined however the test ends.
class InProcessService {
 public:
  InProcessService(const std::string& name, const Config& config, const std::string& out,
                   std::function<void(ServiceContext&)> body)
      : args_("rekon-" + name, "in-process"), ctx_(name, config, out, args_) {
    createOutputFolder(out);
    thread_ = std::thread([this, body = std::move(body)] { status_ = runInContext(ctx_, body); });
  }
  ~InProcessService() {
    ctx_.requestStop();
    if (thread_.joinable()) thread_.join();
  }
  // Its exit status once its body returned.
  int join() {
    thread_.join();
    return status_;
  }

 private:
  ArgParser args_;
  ServiceContext ctx_;
  std::thread thread_;
  int status_ = -1;
};

TEST(MapperResend, FramesSentAgainAreNeitherQueuedTwiceNorDroppedAndEveryFrameIsAcknowledged) {
  test::TempDir dir;
  synth::SequenceOptions sequence;
  sequence.scene = "room";
  sequence.frames = kFrames;
  synth::writeSequence(sequence, dir / "room");
  const TumDataset data(dir / "room");

  // max_queued_frames 2: the old count exceeded it after the first copies; the
  // short progress interval runs the progress log (the worker's counters read
  // from another thread) many times, under TSan too.
  const std::string url = "memory://mapper_resend";
  const Config config = Config::load("", {"lcm.url=" + url, "mapper.max_queued_frames=2", "mapper.kappa=4",
                                          "mapper.wait_for_optimiser=false", "mapper.use_store=false",
                                          "mapper.write_uncorrected_mesh=false", "mapper.progress_interval_s=0.02"});
  BusOptions options = BusOptions::fromConfig(config);
  MemoryBus bus(options);
  std::set<int64_t> acked;  // the handlers run on this thread (bus.handle)
  bool running = false;
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t& m) {
    if (m.service == "mapper" && m.state == "running") running = true;
  });
  bus.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const rekon_msgs::frame_ack_t& m) {
    if (m.service == "mapper") acked.insert(m.frame_id);
  });
  InProcessService service("mapper", config, dir / "out", mapper::runMapperService);
  const auto spinFor = [&](double seconds) {
    const auto end = Clock::now() + std::chrono::duration<double>(seconds);
    while (Clock::now() < end) bus.handle(5);
  };
  const auto deadline = Clock::now() + std::chrono::seconds(60);
  while (!running && Clock::now() < deadline) bus.handle(20);
  ASSERT_TRUE(running) << "the mapper never said it was running";

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
  while (acked.size() < static_cast<size_t>(kFrames) && Clock::now() < ack_deadline) bus.handle(20);
  EXPECT_EQ(acked.size(), static_cast<size_t>(kFrames));
  rekon_msgs::end_of_stream_t end{};
  end.last_frame_id = kFrames - 1;
  end.frames = kFrames;
  for (int i = 0; i < 3; ++i) bus.publish(channel::kEndOfStream, end), spinFor(0.05);
  ASSERT_EQ(service.join(), 0);

  // Each frame counted once: all fused, none dropped, every copy seen as one.
  const std::string stats = test::readText(dir / "out/mapper_stats.json");
  EXPECT_EQ(test::jsonInt(stats, "frames_fused"), kFrames) << stats;
  EXPECT_EQ(test::jsonInt(stats, "frames_dropped"), 0) << stats;
  EXPECT_EQ(test::jsonInt(stats, "frames_received_again"), kFrames * (kCopiesWhileWaiting + kCopiesAfterJoin)) << stats;
  EXPECT_EQ(test::jsonInt(stats, "kf_keyframes"), kFrames / 4) << stats;
}


// A restarted mapper (its keyframe store holds frames 0..7) resumes at frame
// 8, and the player sends every frame from there again once it hears of the
// restart. Before that it may send its newest frame again (acknowledgements
// stalled while the mapper was dead), and the new instance, subscribed
// already, gets that frame first, with its tracked frame (the tracker answers
// a frame sent again with its stored result, once per mapper instance). The
// mapper fused it first, took every frame before it for a copy and dropped
// them all (Faults.KilledMapperIsRestartedAndItsMeshMatchesAnUninterruptedRun:
// "frame 73: DVO keyframe 3 has no pose yet", 16 of 50 frames fused).
TEST(MapperResume, AFrameSentBeforeThePlayerHeardOfTheRestartWaitsForItsTurn) {
  test::TempDir dir;
  synth::SequenceOptions sequence;
  sequence.scene = "room";
  sequence.frames = kFrames;
  synth::writeSequence(sequence, dir / "room");
  const TumDataset data(dir / "room");
  const std::string segment = "rekon_test_resume_" + std::to_string(getpid());
  const Config config = Config::load("", {"lcm.url=memory://mapper_resume", "mapper.kappa=4",
                                          "mapper.wait_for_optimiser=false", "mapper.use_store=true",
                                          "mapper.resume=true", "mapper.store_segment=" + segment,
                                          "mapper.store_mb=64", "mapper.write_uncorrected_mesh=false"});
  MemoryBus bus(BusOptions::fromConfig(config));
  std::set<int> running;  // the pids of mapper instances that said so
  std::set<int64_t> acked;
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t& m) {
    if (m.service == "mapper" && m.state == "running") running.insert(m.pid);
  });
  bus.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const rekon_msgs::frame_ack_t& m) {
    if (m.service == "mapper") acked.insert(m.frame_id);
  });
  const auto spinFor = [&](double seconds) {
    const auto end = Clock::now() + std::chrono::duration<double>(seconds);
    while (Clock::now() < end) bus.handle(5);
  };
  const auto waitUntil = [&](const std::function<bool()>& condition) {
    const auto deadline = Clock::now() + std::chrono::seconds(60);
    while (!condition() && Clock::now() < deadline) bus.handle(20);
    return condition();
  };
  FrameSender sender(bus, TransportMode::kLcm, "", FrameRingLayout{});
  const Trajectory& gt = data.groundTruth();
  const auto sendKeyframe = [&] {
    rekon_msgs::keyframe_t kf{};
    kf.keyframe_id = 0;
    kf.timestamp = data.timestamp(0);
    kf.pose_world = toMsg(gt.front().pose);
    bus.publish(channel::kKeyframes, kf);
  };
  const auto sendImage = [&](int i) {
    const EncodedFrame encoded = data.loadEncoded(static_cast<size_t>(i));
    sender.send(data.decode(static_cast<size_t>(i), encoded), data.intrinsics(), &encoded);
  };
  const auto sendTracked = [&](int i) {
    rekon_msgs::tracked_frame_t t{};
    t.frame_id = i;
    t.timestamp = data.timestamp(static_cast<size_t>(i));
    t.keyframe_id = 0;
    t.pose_in_keyframe = toMsg(gt.front().pose.inverse() * gt[static_cast<size_t>(i)].pose);
    bus.publish(channel::kTrackedFrames, t);
  };
  store::KeyframeStore::remove(segment);
  {
    // The first instance fuses frames 0..7 (two KF keyframes at kappa 4) and
    // is stopped before the end: its store stays.
    InProcessService first("mapper", config, dir / "first", mapper::runMapperService);
    ASSERT_TRUE(waitUntil([&] { return !running.empty(); })) << "the mapper never said it was running";
    sendKeyframe();
    for (int i = 0; i < 8; ++i) sendImage(i), sendTracked(i), spinFor(0.02);
    ASSERT_TRUE(waitUntil([&] { return acked.size() == 8; }));
    spinFor(0.5);
  }
  ASSERT_EQ(store::KeyframeStore::openExisting(segment)->size(), 2u);

  running.clear();
  acked.clear();
  InProcessService restarted("mapper", config, dir / "out", mapper::runMapperService);
  ASSERT_TRUE(waitUntil([&] { return !running.empty(); })) << "the restarted mapper never said it was running";
  sendKeyframe();
  // Frame 11 first: sent before the player heard of the restart, its result republished.
  sendImage(11), sendTracked(11), spinFor(0.2);
  EXPECT_EQ(acked.count(11), 0u) << "acknowledged, the player would take it as read and overrun the ring";
  // The player's rewind: 8..15, each once (the tracker sent 11's result already).
  for (int i = 8; i < kFrames; ++i) {
    sendImage(i);
    if (i != 11) sendTracked(i);
    spinFor(0.02);
  }
  ASSERT_TRUE(waitUntil([&] { return acked.size() == static_cast<size_t>(kFrames - 8); }));
  rekon_msgs::end_of_stream_t end{};
  end.last_frame_id = kFrames - 1;
  end.frames = kFrames;
  for (int i = 0; i < 3; ++i) bus.publish(channel::kEndOfStream, end), spinFor(0.05);
  ASSERT_EQ(restarted.join(), 0);

  // Frames 8..15 fused in order into two KF keyframes, as without the restart.
  const std::string stats = test::readText(dir / "out/mapper_stats.json");
  EXPECT_EQ(test::jsonInt(stats, "restored_keyframes"), 2) << stats;
  EXPECT_EQ(test::jsonInt(stats, "frames_fused"), kFrames - 8) << stats;
  EXPECT_EQ(test::jsonInt(stats, "frames_dropped"), 0) << stats;
  EXPECT_EQ(test::jsonInt(stats, "frames_before_resume"), 1) << stats;
  EXPECT_EQ(test::jsonInt(stats, "kf_keyframes"), 2) << stats;
  store::KeyframeStore::remove(segment);
}

// A frame from another camera (its fx changed) makes the mapping worker
// throw. Before, the service threw that error before writing anything: the
// map of every frame fused until then was lost. Now, as the tracker does, the
// outputs are written first, then the service fails with the worker's error.
TEST(MapperWorkerError, TheMeshOfTheFramesFusedBeforeIsWrittenAndTheServiceFails) {
  test::TempDir dir;
  synth::SequenceOptions sequence;
  sequence.scene = "room";
  sequence.frames = kFrames;
  synth::writeSequence(sequence, dir / "room");
  const TumDataset data(dir / "room");
  const Config config = Config::load("", {"lcm.url=memory://mapper_worker_error", "mapper.kappa=4",
                                          "mapper.wait_for_optimiser=false", "mapper.use_store=false",
                                          "mapper.write_uncorrected_mesh=false"});
  MemoryBus bus(BusOptions::fromConfig(config));
  bool running = false;
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t& m) {
    if (m.service == "mapper" && m.state == "running") running = true;
  });
  InProcessService service("mapper", config, dir / "out", mapper::runMapperService);
  const auto deadline = Clock::now() + std::chrono::seconds(60);
  while (!running && Clock::now() < deadline) bus.handle(20);
  ASSERT_TRUE(running) << "the mapper never said it was running";

  FrameSender sender(bus, TransportMode::kLcm, "", FrameRingLayout{});
  const Trajectory& gt = data.groundTruth();
  rekon_msgs::keyframe_t kf{};
  kf.keyframe_id = 0;
  kf.pose_world = toMsg(gt.front().pose);
  bus.publish(channel::kKeyframes, kf);
  for (int i = 0; i < kFrames; ++i) {
    Intrinsics k = data.intrinsics();
    if (i == kFrames - 1) k.fx *= 1.1;  // the last frame's camera is not the map's
    sender.send(data.decode(static_cast<size_t>(i), data.loadEncoded(static_cast<size_t>(i))), k);
    rekon_msgs::tracked_frame_t t{};
    t.frame_id = i;
    t.keyframe_id = 0;
    t.pose_in_keyframe = toMsg(gt.front().pose.inverse() * gt[static_cast<size_t>(i)].pose);
    bus.publish(channel::kTrackedFrames, t);
    while (bus.handle(0)) {
    }
  }
  EXPECT_EQ(service.join(), 1) << "the worker's error fails the service";
  const Mesh mesh = readPly(dir / "out/mesh.ply");
  EXPECT_GT(mesh.vertices.size(), 1000u) << "the room's surface from the frames fused before the error";
  EXPECT_FALSE(test::readText(dir / "out/mapper_timing.csv").empty());
  EXPECT_EQ(test::jsonInt(test::readText(dir / "out/mapper_stats.json"), "frames_fused"), kFrames - 1);
}

}  // namespace
}  // namespace rekon
