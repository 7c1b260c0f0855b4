// Tracking loss as a run reports it (issue 18): LostIntervals on tracking
// results, and a real sequence with the lens covered for 20 frames through
// the whole pipeline: the loss is found and reported, nothing is fused while
// lost, and tracking goes on. Without relocalisation (not built yet) it goes
// on from the last good pose, and the trajectory after the gap is off by the
// motion during it: this test guards today's numbers, stated below.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "rekon/tracker/lost_intervals.hpp"
#include "test_support.hpp"

namespace rekon::tracker {
namespace {

namespace fs = std::filesystem;
using rekon::test::binDir;
using rekon::test::jsonInt;
using rekon::test::readText;
using rekon::test::runCommand;

TrackResult result(int64_t id, bool lost, LostReason reason = LostReason::None, bool reset = false) {
  TrackResult r;
  r.frame_id = id;
  r.timestamp = 0.1 * static_cast<double>(id);
  r.state = lost ? TrackingState::Lost : TrackingState::Ok;
  r.lost_reason = reason;
  r.keyframe_reset = reset;
  return r;
}

TEST(LostIntervals, EachRunOfLostFramesIsOneIntervalWithItsReasonAndEnd) {
  LostIntervals l;
  l.add(result(0, false));
  for (int64_t f = 1; f <= 3; ++f) l.add(result(f, true, LostReason::BlackImage));
  l.add(result(4, false));
  for (int64_t f = 5; f <= 8; ++f) l.add(result(f, true, LostReason::LargeResidual, f == 8));
  l.add(result(9, true, LostReason::NoDepth));
  l.add(result(10, true, LostReason::NoDepth));
  l.finish();
  ASSERT_EQ(l.intervals().size(), 3u);
  const LostInterval& a = l.intervals()[0];
  EXPECT_EQ(a.first_frame, 1);
  EXPECT_EQ(a.last_frame, 3);
  EXPECT_EQ(a.frames, 3);
  EXPECT_NEAR(a.seconds, 0.3, 1e-9);  // frame 1 to the frame that resumed (4)
  EXPECT_EQ(a.reason, "black image");
  EXPECT_EQ(a.ended, "tracking resumed");
  EXPECT_EQ(l.intervals()[1].frames, 4);
  EXPECT_EQ(l.intervals()[1].ended, "restarted at the last good pose");
  EXPECT_EQ(l.intervals()[2].first_frame, 9);
  EXPECT_EQ(l.intervals()[2].ended, "end of stream");
  EXPECT_EQ(l.count(), 3);
  EXPECT_NE(l.json().find(R"({"first_frame":1,"last_frame":3,"frames":3,"seconds":0.300,"reason":"black image","ended":"tracking resumed"})"),
            std::string::npos) << l.json();
}

// The first `frames` frames of a TUM dataset, with frames [from, from + n)
// replaced by a covered lens: black color, no depth. Everything else links
// to the original files.
void coveredLens(const std::string& src, const std::string& dst, int frames, int from, int n) {
  fs::create_directories(dst);
  for (const char* f : {"camera.yaml", "groundtruth.txt"}) fs::copy_file(fs::path(src) / f, fs::path(dst) / f);
  fs::create_directory_symlink(fs::absolute(fs::path(src) / "rgb"), fs::path(dst) / "rgb");
  fs::create_directory_symlink(fs::absolute(fs::path(src) / "depth"), fs::path(dst) / "depth");
  cv::Mat black(480, 640, CV_8UC3, cv::Scalar::all(0)), no_depth(480, 640, CV_16U, cv::Scalar::all(0));
  cv::imwrite(dst + "/black.png", black);
  cv::imwrite(dst + "/no_depth.png", no_depth);
  for (const char* list : {"rgb.txt", "depth.txt"}) {
    std::ifstream in(fs::path(src) / list);
    std::ofstream out(fs::path(dst) / list);
    int i = 0;
    for (std::string line; std::getline(in, line) && i < frames;) {
      if (line.empty() || line[0] == '#') continue;
      std::istringstream s(line);
      std::string ts, file;
      s >> ts >> file;
      const bool covered = i >= from && i < from + n;
      out << ts << ' ' << (covered ? (std::string(list) == "rgb.txt" ? "black.png" : "no_depth.png") : file) << '\n';
      ++i;
    }
  }
}

double ate(const std::string& groundtruth, const std::string& trajectory) {
  std::string out;
  runCommand(binDir() + "/rekon eval traj " + groundtruth + " " + trajectory, &out);
  return rekon::test::valueAfter(out, "ate_rmse_m");
}

// Measured: frames 150-169 are lost (no valid depth), 170-179 do not align
// to the keyframe (the camera moved 0.67 s meanwhile), and at frame 179
// (tracker.max_lost_frames = 30 in a row) the tracker restarts at the last
// good pose; the mapper skips all 30. ATE 57.1 mm against 19.9 mm uncovered
// (2.9x): relocalisation against the keyframes is what would bring it back.
TEST(LostIntervals, CoveredLensOnARealSequenceIsLostNotFusedAndTrackingGoesOn) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  rekon::test::TempDir dir;
  constexpr int kFrames = 300, kFrom = 150, kCovered = 20;
  coveredLens(data, dir / "covered", kFrames, kFrom, kCovered);
  coveredLens(data, dir / "plain", kFrames, 0, 0);
  std::string out;
  for (const char* name : {"covered", "plain"}) {
    ASSERT_EQ(runCommand(rekon::test::inNetns() + " timeout 240 " + binDir() + "/rekon run --dataset " + (dir / name) +
                             " --out " + (dir / (std::string(name) + "_run")),
                         &out), 0) << out;
  }
  const std::string tracker = readText(dir / "covered_run/tracker_stats.json");
  const std::string mapper = readText(dir / "covered_run/mapper_stats.json");
  EXPECT_EQ(jsonInt(tracker, "lost_intervals_count"), 1) << tracker;
  // The interval starts with the cover and ends within max_lost_frames (30) of it.
  EXPECT_NE(tracker.find(R"("first_frame":150,)"), std::string::npos) << tracker;
  EXPECT_NE(tracker.find(R"("reason":"no valid depth")"), std::string::npos) << tracker;
  const long long lost = jsonInt(tracker, "lost_frames");
  EXPECT_GE(lost, kCovered) << tracker;
  EXPECT_LE(lost, 30) << tracker;
  EXPECT_EQ(jsonInt(mapper, "frames_skipped"), lost) << mapper;  // nothing fused while lost
  EXPECT_EQ(jsonInt(mapper, "frames_fused"), kFrames - lost) << mapper;
  // The covered run's ATE (its covered frames carry the last good pose) against the plain run's.
  const double covered = ate(data + "/groundtruth.txt", dir / "covered_run/trajectory.txt");
  const double plain = ate(data + "/groundtruth.txt", dir / "plain_run/trajectory.txt");
  EXPECT_GT(plain, 0.0);
  EXPECT_LT(covered, 4.0 * plain);  // 2.9x measured
  std::cout << "ATE covered " << covered << " m, plain " << plain << " m\n";
}

}  // namespace
}  // namespace rekon::tracker
