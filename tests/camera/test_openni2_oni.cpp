// The OpenNI2 driver on .oni recordings, end to end through OpenNI2 itself:
// rekon-oni-record records the synthetic device of tools/oni/synth_driver.cpp
// with OpenNI2's own openni::Recorder, and openOpenNI2 replays the file
// through OpenNI2's own file device (OniFile). No camera is needed.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include "rekon/camera/source.hpp"
#include "rekon/common/error.hpp"
#include "test_support.hpp"

namespace rekon::camera {
namespace {

using Clock = std::chrono::steady_clock;

// The synthetic device (tools/oni/synth_driver.cpp), 320x240@30, frame k = 1, 2, ...:
//   depth mm: row 0 = 2000, else 1000 + x + y + 10 * (k % 50)
//   color: R = k % 256, G = y, B = x % 256
//   field of view: 1.0225 rad horizontal, 0.7941 rad vertical
uint16_t synthDepth(int x, int y, int k) {
  return y == 0 ? 2000 : static_cast<uint16_t>(1000 + x + y + 10 * (k % 50));
}
constexpr double kSynthHfov = 1.0225, kSynthVfov = 0.7941;

// Runs rekon-oni-record; its exit status, its output in `log`.
int recordOni(const std::string& device, const std::string& out, int frames, std::string* log) {
  const std::string log_path = out + ".log";
  const pid_t pid = test::spawnShell(test::binDir() + "/rekon-oni-record --device '" + device + "' --out '" + out +
                                     "' --frames " + std::to_string(frames) + " >'" + log_path + "' 2>&1");
  const int status = pid < 0 ? -1 : test::waitForExit(pid, 60.0);
  *log = test::readText(log_path);
  return status;
}

// A recording of the synthetic device, made once for the tests that only read it.
class SynthRecording : public ::testing::Test {
 protected:
  static constexpr int kFrames = 60;  // 2 s at 30 Hz
  static void SetUpTestSuite() {
    dir_ = new test::TempDir();
    std::string log;
    ASSERT_EQ(recordOni("rekon-synth", path(), kFrames, &log), 0) << log;
    // What OpenNI2's file device counts in the recording, as the tool reports it.
    const size_t at = log.find("recorded ");
    int depth = 0, color = 0;
    ASSERT_NE(at, std::string::npos) << log;
    ASSERT_EQ(std::sscanf(log.c_str() + at, "recorded %d depth and %d color", &depth, &color), 2) << log;
    recorded_ = std::min(depth, color);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static std::string path() { return *dir_ / "synth.oni"; }
  static test::TempDir* dir_;
  static int recorded_;
};
test::TempDir* SynthRecording::dir_ = nullptr;
int SynthRecording::recorded_ = 0;

// The tool counts frames once OpenNI2's Recorder writes them, so it records
// at least the frames asked; one or two more (measured: 62 of 60 in 10 runs)
// are raised before it sees the first written and after its last read.
TEST_F(SynthRecording, RecorderWritesTheFramesAsked) {
  EXPECT_GE(recorded_, kFrames);
  EXPECT_LE(recorded_, kFrames + 3);
}

struct Playback {
  std::vector<RgbdFrame> frames;
  Capture last;  // the capture that ended it
  double seconds = 0.0;
};

// `consume_s`: how long the reader spends on each frame before the next.
Playback playToEnd(CameraSource& source, double limit_s, double consume_s = 0.0) {
  Playback playback;
  const auto start = Clock::now();
  while (std::chrono::duration<double>(Clock::now() - start).count() < limit_s) {
    Capture capture = source.next(1.0);
    if (capture.status == Capture::Status::kFrame) {
      playback.frames.push_back(std::move(capture.frame));
      std::this_thread::sleep_for(std::chrono::duration<double>(consume_s));
    } else if (capture.status != Capture::Status::kTimeout) {
      playback.last = capture;
      break;
    }
  }
  playback.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return playback;
}

// The frame index a synthetic color image carries (red channel; the
// recordings here are shorter than 256 frames).
int synthIndex(const RgbdFrame& frame) { return frame.color.at<cv::Vec3b>(0, 0)[2]; }

TEST_F(SynthRecording, PlaysEveryRecordedFrameOnceThenEnds) {
  auto source = openOpenNI2(path(), {});
  const Playback playback = playToEnd(*source, 30.0);
  EXPECT_EQ(playback.last.status, Capture::Status::kEnded) << playback.last.reason;
  std::string indices;
  for (const RgbdFrame& frame : playback.frames) indices += std::to_string(synthIndex(frame)) + " ";
  // Every recorded pair, in order. A reader stalled for more than a frame
  // period loses the older frames (newest wins, as with a camera): measured
  // none lost in 7 runs and 4 in one (a 130 ms stall, two compilers on the
  // machine's two cores); 10 % allowed.
  EXPECT_LE(int(playback.frames.size()), recorded_) << indices;
  EXPECT_GE(int(playback.frames.size()), recorded_ - recorded_ / 10) << indices;
  EXPECT_EQ(int(playback.frames.size() + source->framesReplaced()), recorded_) << "every frame taken or counted";
  for (size_t i = 1; i < playback.frames.size(); ++i)
    EXPECT_GT(synthIndex(playback.frames[i]), synthIndex(playback.frames[i - 1])) << indices;
  if (!playback.frames.empty()) {
    EXPECT_EQ(synthIndex(playback.frames.back()) - synthIndex(playback.frames.front()) + 1, recorded_) << indices;
  }
  std::printf("recorded %d, played %zu: %s\n", recorded_, playback.frames.size(), indices.c_str());
}

TEST_F(SynthRecording, SlowReaderGetsTheNewestFrameAndEveryOtherIsCountedAsReplaced) {
  // A reader that needs 100 ms per frame of a 30 Hz recording takes about
  // every third frame; the file device keeps only the newest, and the ones
  // in between are the camera's frames_skipped_late. Every frame between the
  // first and the last taken is either taken or counted.
  auto source = openOpenNI2(path(), {});
  const Playback playback = playToEnd(*source, 30.0, 0.1);
  EXPECT_EQ(playback.last.status, Capture::Status::kEnded) << playback.last.reason;
  ASSERT_GE(playback.frames.size(), size_t{2});
  const int span = synthIndex(playback.frames.back()) - synthIndex(playback.frames.front()) + 1;
  const int taken = static_cast<int>(playback.frames.size()), replaced = static_cast<int>(source->framesReplaced());
  std::printf("slow reader: %d of %d frames taken, %d replaced\n", taken, span, replaced);
  EXPECT_EQ(taken + replaced, span);
  // 2 s at 0.1 s per frame: about 20 taken of 60; a loaded machine only
  // takes fewer, so "most were replaced" is what holds anywhere.
  EXPECT_GT(replaced, taken);
}

TEST_F(SynthRecording, DepthAndColorArePairedAndConverted) {
  auto source = openOpenNI2(path(), {});
  const Playback playback = playToEnd(*source, 30.0);
  ASSERT_FALSE(playback.frames.empty());
  for (const RgbdFrame& frame : playback.frames) {
    ASSERT_EQ(frame.depth.type(), CV_16UC1);
    ASSERT_EQ(frame.color.type(), CV_8UC3);
    ASSERT_EQ(frame.depth.size(), cv::Size(320, 240));
    ASSERT_EQ(frame.color.size(), cv::Size(320, 240));
    const int k = synthIndex(frame);
    int wrong_depth = 0, wrong_color = 0;
    for (int y = 0; y < 240; ++y)
      for (int x = 0; x < 320; ++x) {
        wrong_depth += frame.depth.at<uint16_t>(y, x) != synthDepth(x, y, k);  // same k: a pair
        const cv::Vec3b bgr = frame.color.at<cv::Vec3b>(y, x);
        wrong_color += bgr != cv::Vec3b(uint8_t(x % 256), uint8_t(y), uint8_t(k % 256));
      }
    ASSERT_EQ(wrong_depth, 0) << "frame " << k;  // lossless: 16z codec for depth,
    ASSERT_EQ(wrong_color, 0) << "frame " << k;  // uncompressed color
  }
}

TEST_F(SynthRecording, PlaysAtTheRecordedRateStampedWithTheHostClock) {
  auto source = openOpenNI2(path(), {});
  const double before = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  const Playback playback = playToEnd(*source, 30.0);
  ASSERT_GE(playback.frames.size(), size_t{2});
  const double span = playback.frames.back().timestamp - playback.frames.front().timestamp;
  const int intervals = synthIndex(playback.frames.back()) - synthIndex(playback.frames.front());
  std::printf("%zu frames over %.3f s\n", playback.frames.size(), span);
  // The recorded rate is 30 Hz (33.3 ms a frame); measured within 1 %. 0.1 s
  // margin (5 %) for a loaded machine.
  EXPECT_NEAR(span, intervals / 30.0, 0.1);
  EXPECT_GE(playback.frames.front().timestamp, before);
  for (size_t i = 1; i < playback.frames.size(); ++i)
    EXPECT_GT(playback.frames[i].timestamp, playback.frames[i - 1].timestamp);
}

TEST_F(SynthRecording, IntrinsicsComeFromTheRecordedFieldOfView) {
  auto source = openOpenNI2(path(), {});
  const Intrinsics k = source->intrinsics();
  EXPECT_EQ(k.width, 320);
  EXPECT_EQ(k.height, 240);
  // fx = w / (2 tan(hfov / 2)) = 285.2; the file keeps the FOV as a float.
  EXPECT_NEAR(k.fx, 320 / (2 * std::tan(kSynthHfov / 2)), 1e-3);
  EXPECT_NEAR(k.fy, 240 / (2 * std::tan(kSynthVfov / 2)), 1e-3);
  EXPECT_DOUBLE_EQ(k.cx, 159.5);
  EXPECT_DOUBLE_EQ(k.cy, 119.5);
  EXPECT_DOUBLE_EQ(k.depth_scale, 1000.0);  // millimetres
  EXPECT_NE(source->describe().find("field of view"), std::string::npos) << source->describe();
  EXPECT_NE(source->describe().find("registered as recorded"), std::string::npos) << source->describe();
}

TEST_F(SynthRecording, CalibrationFileOverridesTheDevice) {
  const std::string yaml = *dir_ / "camera.yaml";
  std::ofstream(yaml) << "320 240 300 301 160 120 1000\n";
  SourceOptions options;
  options.calibration_file = yaml;
  auto source = openOpenNI2(path(), options);
  EXPECT_DOUBLE_EQ(source->intrinsics().fx, 300.0);
  EXPECT_DOUBLE_EQ(source->intrinsics().fy, 301.0);

  std::ofstream(yaml) << "640 480 525 525 319.5 239.5 1000\n";  // another camera mode
  EXPECT_THROW(openOpenNI2(path(), options), Error);
}

// Depth-camera keys (kinect_depth.hpp) register depth in software: with the
// depth camera where the color camera is, the warp changes no pixel.
TEST_F(SynthRecording, CalibrationWithDepthCameraKeysRegistersInSoftware) {
  const std::string yaml = *dir_ / "registration.yaml";
  std::ofstream(yaml) << "{width: 320, height: 240, fx: 285, fy: 286, cx: 159.5, cy: 119.5, depth_scale: 1000,\n"
                         " depth_camera: {fx: 285, fy: 286, cx: 159.5, cy: 119.5}, depth_to_color_translation: [0, 0, 0]}\n";
  SourceOptions options;
  options.calibration_file = yaml;
  auto source = openOpenNI2(path(), options);
  EXPECT_NE(source->describe().find("in software"), std::string::npos) << source->describe();
  Capture capture;
  while ((capture = source->next(1.0)).status == Capture::Status::kTimeout) {
  }
  ASSERT_EQ(capture.status, Capture::Status::kFrame) << capture.reason;
  const int k = synthIndex(capture.frame);
  int wrong = 0;
  for (int y = 0; y < 240; ++y)
    for (int x = 0; x < 320; ++x) wrong += capture.frame.depth.at<uint16_t>(y, x) != synthDepth(x, y, k);
  EXPECT_EQ(wrong, 0);
}

// What a user sees: one line naming the file, no crash, no hang.
void expectOneLineError(const std::string& uri, const std::string& must_name) {
  try {
    openOpenNI2(uri, {});
    ADD_FAILURE() << "opening " << uri << " should fail";
  } catch (const Error& e) {
    const std::string line = e.what();
    EXPECT_EQ(line.find('\n'), std::string::npos) << line;
    EXPECT_NE(line.find(must_name), std::string::npos) << line;
  }
}

TEST(OniFile, MissingFileIsOneErrorLine) {
  test::TempDir dir;
  expectOneLineError(dir / "absent.oni", "absent.oni");
}

TEST(OniFile, FileThatIsNoRecordingIsOneErrorLine) {
  test::TempDir dir;
  std::ofstream(dir / "text.oni") << "not an OpenNI recording\n";
  expectOneLineError(dir / "text.oni", "text.oni");
  std::ofstream(dir / "empty.oni");
  expectOneLineError(dir / "empty.oni", "empty.oni");
}

// A recording cut short (a disk that filled up, a copy interrupted) or
// damaged inside: one error line at opening, or the frames before the damage
// and then an end or a loss, within the loss timeout; never a crash or hang.
// (OpenNI2's Recorder leaves zeros after its last record, about half of the
// file here: the damage is placed by the data before them.)
struct Damage {
  std::string name;
  double at;          // fraction of the data (0: just after the 24-byte file header)
  size_t zeroed = 0;  // bytes zeroed there (records and their headers); 0 = cut the file there
};

void damage(const std::string& from, const std::string& to, const Damage& d) {
  std::string bytes = test::readText(from);
  const size_t data = bytes.find_last_not_of('\0') + 1;
  const size_t at = d.at > 0 ? static_cast<size_t>(double(data) * d.at) : 24;
  if (d.zeroed == 0) {
    bytes.resize(at);
  } else {
    std::fill_n(bytes.begin() + static_cast<std::ptrdiff_t>(at), d.zeroed, '\0');
  }
  std::ofstream(to, std::ios::binary) << bytes;
}

TEST_F(SynthRecording, DamagedRecordingIsOneLineNeverACrashOrHang) {
  for (const Damage& d : {Damage{"cut_after_end_record", 1.0}, Damage{"cut_half", 0.5}, Damage{"cut_head", 0.02}, Damage{"zeroed_middle", 0.5, 1 << 20},
                          Damage{"zeroed_head", 0, 4096}}) {
    const std::string file = *dir_ / (d.name + ".oni");
    damage(path(), file, d);
    const auto start = Clock::now();
    try {
      auto source = openOpenNI2(file, {});
      const Playback playback = playToEnd(*source, 20.0);
      EXPECT_TRUE(playback.last.status == Capture::Status::kEnded || playback.last.status == Capture::Status::kLost)
          << d.name << ": no end within 20 s";
      EXPECT_EQ(playback.last.reason.find('\n'), std::string::npos);
      // Only a cut after the END record (the zeros OpenNI2 needs are gone) keeps every frame.
      EXPECT_LE(int(playback.frames.size()), d.at < 1.0 ? recorded_ - 1 : recorded_) << d.name;
      std::printf("%s: %zu frames, then %s after %.1f s: %s\n", d.name.c_str(), playback.frames.size(),
                  playback.last.status == Capture::Status::kEnded ? "ended" : "lost",
                  std::chrono::duration<double>(Clock::now() - start).count(), playback.last.reason.c_str());
    } catch (const Error& e) {
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
      EXPECT_NE(std::string(e.what()).find(file), std::string::npos) << e.what();
      std::printf("%s: %s\n", d.name.c_str(), e.what());
    }
  }
}

// OpenNI2's DummyDevice records (the Recorder accepts it) but its streams
// report no cropping, and OpenNI2 2.2's file player drops every frame of such
// a recording: the user gets one line saying so, not an endless wait. If this
// fails because frames arrive, OpenNI2 was fixed and Dummy can replace
// rekon-synth in these tests.
TEST(OniFile, DummyDeviceRecordingPlaysEmptyAndSaysWhy) {
  test::TempDir dir;
  std::string log;
  ASSERT_EQ(recordOni("Dummy", dir / "dummy.oni", 10, &log), 0) << log;
  auto source = openOpenNI2(dir / "dummy.oni", {});
  const Playback playback = playToEnd(*source, 20.0);
  EXPECT_TRUE(playback.frames.empty());
  EXPECT_EQ(playback.last.status, Capture::Status::kLost);
  EXPECT_NE(playback.last.reason.find("DummyDevice"), std::string::npos) << playback.last.reason;
}

TEST(OniRecorder, DeviceThatDoesNotExistIsOneLineAndExitStatusOne) {
  test::TempDir dir;
  std::string log;
  EXPECT_EQ(recordOni("no-such-device", dir / "x.oni", 3, &log), 1);
  EXPECT_NE(log.find("no-such-device"), std::string::npos) << log;
  EXPECT_EQ(test::crashLines(log), "") << log;
}

}  // namespace
}  // namespace rekon::camera
