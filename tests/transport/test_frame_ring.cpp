#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <boost/interprocess/mapped_region.hpp>
#include <boost/interprocess/shared_memory_object.hpp>
#include <opencv2/core.hpp>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/common/frame_ring.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/messages.hpp"

namespace {

std::string uniqueName(const char* what) { return std::string("rekon_test_") + what + "_" + std::to_string(getpid()); }

// A frame whose every pixel encodes `value`, so a torn copy is visible.
rekon::RgbdFrame uniformFrame(int64_t id, int value, int w = 64, int h = 48) {
  rekon::RgbdFrame f;
  f.id = id;
  f.timestamp = id / 30.0;
  f.depth = cv::Mat(h, w, CV_16UC1, cv::Scalar(value));
  f.color = cv::Mat(h, w, CV_8UC3, cv::Scalar(value & 255, (value >> 8) & 255, 7));
  return f;
}

bool isUniform(const rekon::RgbdFrame& f) {
  double lo, hi;
  cv::minMaxLoc(f.depth, &lo, &hi);
  return lo == hi;
}

}  // namespace

TEST(FrameRing, FrameReadsBackBitExact) {
  rekon::FrameRingWriter w(uniqueName("exact"), {4, 64, 48});
  rekon::RgbdFrame f = uniformFrame(5, 1234);
  f.depth.at<uint16_t>(3, 7) = 9;
  const uint64_t gen = w.write(1, f);
  rekon::FrameRingReader r(w.name());
  rekon::RgbdFrame out;
  ASSERT_EQ(r.read(1, gen, &out), rekon::FrameRingReader::Status::kOk);
  EXPECT_EQ(out.id, 5);
  EXPECT_EQ(cv::norm(out.depth, f.depth, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(out.color, f.color, cv::NORM_INF), 0.0);
}

TEST(FrameRing, OverwrittenSlotIsDetected) {
  rekon::FrameRingWriter w(uniqueName("over"), {4, 64, 48});
  const uint64_t gen = w.write(0, uniformFrame(0, 1));
  w.write(0, uniformFrame(4, 2));
  rekon::FrameRingReader r(w.name());
  rekon::RgbdFrame out;
  EXPECT_EQ(r.read(0, gen, &out), rekon::FrameRingReader::Status::kOverwritten);
}

TEST(FrameRing, WriteDuringReadIsDetectedAsTorn) {
  rekon::FrameRingWriter w(uniqueName("torn"), {4, 64, 48});
  const uint64_t gen = w.write(2, uniformFrame(2, 10));
  rekon::FrameRingReader r(w.name());
  rekon::RgbdFrame out;
  const auto status = r.read(2, gen, &out, [&] { w.write(2, uniformFrame(6, 20)); });
  EXPECT_EQ(status, rekon::FrameRingReader::Status::kTorn);
}

TEST(FrameRing, OutOfRangeSlotAndOddGenerationAreBadReferences) {
  rekon::FrameRingWriter w(uniqueName("range"), {4, 64, 48});
  rekon::FrameRingReader r(w.name());
  rekon::RgbdFrame out;
  EXPECT_EQ(r.read(4, 2, &out), rekon::FrameRingReader::Status::kBadReference);
  EXPECT_EQ(r.read(-1, 2, &out), rekon::FrameRingReader::Status::kBadReference);
  EXPECT_EQ(r.read(0, 3, &out), rekon::FrameRingReader::Status::kBadReference);
}

TEST(FrameRing, WriterRacingReaderNeverYieldsAMixedFrame) {
  rekon::FrameRingWriter w(uniqueName("race"), {2, 320, 240});
  std::atomic<uint64_t> latest{w.write(0, uniformFrame(0, 0, 320, 240))};
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    for (int v = 1; !stop.load(); ++v) latest.store(w.write(0, uniformFrame(v, v & 0xffff, 320, 240)));
  });
  rekon::FrameRingReader r(w.name());
  int ok = 0, torn = 0, mixed = 0;
  for (int i = 0; i < 3000; ++i) {
    rekon::RgbdFrame out;
    const auto s = r.read(0, latest.load(), &out);
    if (s == rekon::FrameRingReader::Status::kOk) {
      ++ok;
      if (!isUniform(out)) ++mixed;
    } else if (s == rekon::FrameRingReader::Status::kTorn) {
      ++torn;
    }
  }
  stop = true;
  writer.join();
  EXPECT_EQ(mixed, 0) << "a frame overwritten during the copy was returned as valid";
  RecordProperty("ok_reads", ok);
  RecordProperty("torn_reads", torn);
}

TEST(FrameRing, StaleSegmentOfACrashedRunIsRecreated) {
  namespace bip = boost::interprocess;
  const std::string name = uniqueName("stale");
  {
    // What a crashed writer leaves: a segment whose creator pid no longer runs.
    bip::shared_memory_object shm(bip::create_only, name.c_str(), bip::read_write);
    shm.truncate(4096);
    bip::mapped_region region(shm, bip::read_write);
    std::memset(region.get_address(), 0, 4096);
    const uint64_t magic = 0x31524652454b4552ull;
    std::memcpy(region.get_address(), &magic, 8);
    const int32_t dead_pid = 0x3ffffff0;  // above pid_max: never a live process
    std::memcpy(static_cast<char*>(region.get_address()) + 12, &dead_pid, 4);
  }
  rekon::FrameRingWriter w(name, {4, 64, 48});
  rekon::FrameRingReader r(name);
  rekon::RgbdFrame out;
  EXPECT_EQ(r.read(0, w.write(0, uniformFrame(0, 3)), &out), rekon::FrameRingReader::Status::kOk);
}

TEST(FrameRing, SegmentOfALiveRunIsNotTakenOver) {
  rekon::FrameRingWriter w(uniqueName("live"), {4, 64, 48});
  EXPECT_THROW(rekon::FrameRingWriter(w.name(), {4, 64, 48}), rekon::Error);
}

TEST(FrameRing, MissingSegmentIsAClearError) {
  try {
    rekon::FrameRingReader r(uniqueName("missing"));
    FAIL();
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("transport.mode"), std::string::npos) << e.what();
  }
}

TEST(FrameRing, SegmentIsRemovedWhenTheWriterCloses) {
  const std::string name = uniqueName("closed");
  { rekon::FrameRingWriter w(name, {2, 8, 8}); }
  EXPECT_THROW(rekon::FrameRingReader r(name), rekon::Error);
}

TEST(FrameRing, FrameLargerThanASlotIsAnError) {
  rekon::FrameRingWriter w(uniqueName("large"), {2, 32, 24});
  EXPECT_THROW(w.write(0, uniformFrame(0, 1, 64, 48)), rekon::Error);
}

namespace {

// What a frame source process does before it is killed: creates the ring,
// writes frame `id` into slot 0 and dies without removing the segment.
// Returns the frame's message as the receiver gets it.
rekon_msgs::frame_t writeInAProcessThatDies(const std::string& name, int64_t id, int value) {
  int fds[2];
  EXPECT_EQ(pipe(fds), 0);
  const pid_t child = fork();
  if (child == 0) {
    rekon::FrameRingWriter w(name, {2, 64, 48});
    const uint64_t generation = w.write(0, uniformFrame(id, value));
    (void)!write(fds[1], &generation, sizeof generation);
    _exit(0);  // as kill -9: no destructor removes the segment
  }
  uint64_t generation = 0;
  EXPECT_EQ(read(fds[0], &generation, sizeof generation), static_cast<ssize_t>(sizeof generation));
  close(fds[0]);
  close(fds[1]);
  waitpid(child, nullptr, 0);
  rekon_msgs::frame_t msg{};
  msg.frame_id = id;
  rekon::Intrinsics k;
  k.width = 64, k.height = 48, k.fx = k.fy = 50, k.cx = 32, k.cy = 24, k.depth_scale = 1000;
  rekon::setIntrinsics(k, &msg);
  msg.shm_segment = name;
  msg.shm_slot = 0;
  msg.shm_generation = static_cast<int64_t>(generation);
  return msg;
}

}  // namespace

// A frame source killed and started again creates its ring again under the
// same name. A receiver still mapping the old one (unlinked, still readable)
// would find none of the new frames there and drop every one; it reopens
// the segment instead (issue 48).
TEST(FrameRing, AReceiverReadsTheRingOfARestartedSource) {
  const std::string name = uniqueName("restarted");
  rekon::FrameReceiver receiver;
  const auto first = receiver.receive(writeInAProcessThatDies(name, 0, 100), nullptr);
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->depth.at<uint16_t>(0, 0), 100);
  const auto second = receiver.receive(writeInAProcessThatDies(name, 1, 200), nullptr);
  ASSERT_TRUE(second.has_value()) << "a frame of the restarted source was dropped";
  EXPECT_EQ(second->id, 1);
  EXPECT_EQ(second->depth.at<uint16_t>(0, 0), 200);
  EXPECT_EQ(receiver.dropped(), 0u);
  rekon::removeFrameRing(name);
}
