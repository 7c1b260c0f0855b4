// Tracking loss as a run reports it (issue 18): LostIntervals on tracking
// results, and a real sequence through the whole pipeline with the lens
// covered for 20 frames, and with 50 frames cut out so that the camera jumps:
// the loss is found and reported, nothing is fused while lost, and tracking
// goes on, relocalised against the keyframes where the camera is somewhere
// they saw, else from the last good pose.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "rekon/common/pose.hpp"
#include "rekon/tracker/lost_intervals.hpp"
#include "test_support.hpp"

namespace rekon::tracker {
namespace {

namespace fs = std::filesystem;
using rekon::test::ateOf;
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
  TrackResult relocalised = result(11, false);
  relocalised.relocalised_from = OdometryConstraint{};
  l.add(relocalised);
  l.add(result(12, true, LostReason::GapInTheData));
  l.finish();
  ASSERT_EQ(l.intervals().size(), 4u);
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
  EXPECT_EQ(l.intervals()[2].ended, "relocalised");
  EXPECT_EQ(l.intervals()[3].reason, "gap in the data");
  EXPECT_EQ(l.intervals()[3].ended, "end of stream");
  EXPECT_EQ(l.count(), 4);
  EXPECT_NE(l.json().find(R"({"first_frame":1,"last_frame":3,"frames":3,"seconds":0.300,"reason":"black image","ended":"tracking resumed"})"),
            std::string::npos) << l.json();
}

enum class Edit { CoverLens, CutOut };

// The first `frames` frames of a TUM dataset with frames [from, from + n)
// replaced by a covered lens (black color, no depth) or cut out (the camera
// jumps). Everything else links to the original files.
void editedSequence(const std::string& src, const std::string& dst, int frames, int from, int n, Edit edit) {
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
      const bool inside = i >= from && i < from + n;
      ++i;
      if (inside && edit == Edit::CutOut) continue;
      if (inside) file = std::string(list) == "rgb.txt" ? "black.png" : "no_depth.png";
      out << ts << ' ' << file << '\n';
    }
  }
}

// `rekon run` on the first `frames` frames of `src` edited as editedSequence
// (outputs in DIR/edited_run) and on the same frames unedited (DIR/whole_run).
void runEditedAndWhole(const std::string& src, const rekon::test::TempDir& dir, int frames, int from, int n, Edit edit) {
  editedSequence(src, dir / "edited", frames, from, n, edit);
  editedSequence(src, dir / "whole", frames, 0, 0, edit);
  for (const char* name : {"edited", "whole"}) {
    std::string out;
    ASSERT_EQ(runCommand(rekon::test::inNetns() + " timeout 300 " + binDir() + "/rekon run --dataset " + (dir / name) +
                             " --out " + (dir / (std::string(name) + "_run")),
                         &out), 0) << out;
  }
}

// Measured: frames 150-169 are lost (no valid depth); 170-179 neither align
// to the keyframe nor relocalise (the camera moved on for 0.67 s, into a view
// no keyframe holds: the best candidates reach ln det ratio 0.85-0.88 at the
// fine stage, below 0.9, and accepting 0.88 placed the camera 0.35 m wrong),
// and at frame 179 (tracker.max_lost_frames = 30 in a row) the tracker
// restarts at the last good pose; the mapper skips all 30. ATE 58.2 mm
// (the lost frames are not in trajectory.txt) against 19.9 mm uncovered (2.9x).
TEST(LostIntervals, CoveredLensOnARealSequenceIsLostNotFusedAndTrackingGoesOn) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  rekon::test::TempDir dir;
  constexpr int kFrames = 300, kFrom = 150, kCovered = 20;
  ASSERT_NO_FATAL_FAILURE(runEditedAndWhole(data, dir, kFrames, kFrom, kCovered, Edit::CoverLens));
  const std::string tracker = readText(dir / "edited_run/tracker_stats.json");
  const std::string mapper = readText(dir / "edited_run/mapper_stats.json");
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
  const double covered = ateOf(data + "/groundtruth.txt", dir / "edited_run/trajectory.txt");
  const double plain = ateOf(data + "/groundtruth.txt", dir / "whole_run/trajectory.txt");
  EXPECT_GT(plain, 0.0);
  EXPECT_LT(covered, 4.0 * plain);  // 2.9x measured
  std::cout << "ATE covered " << covered << " m, plain " << plain << " m\n";
}

// Frames 900-949 of the 7-Scenes loop cut out: 1.7 s, the camera jumps 0.50 m
// and 21 degrees, back into the part of the room its first minute mapped.
// Frame 900 (after the cut) comes 1.70 s after the last good one, beyond
// tracker.lost_max_gap_s: it is aligned to the last good frame across the gap
// (8085e6a; before, it was lost and relocalised 6 frames later: aligning it
// to the keyframe from the usual guess had kept 0.36 m for the jump, a wrong
// pose that passed every check). Measured: bridged with 0.498 m and 18.8
// degrees against the ground truth's 0.499 m and 20.7 (8 mm and 1.9 degrees
// off), 0 frames lost, ATE 35.1 mm against 37.3 mm uncut. Bounds: the jump
// within 3 cm and 5 degrees (4x and 2.6x the measured), ATE within 1.3x of
// the uncut run's.
TEST(LostIntervals, ACutInARealSequenceIsBridgedFromTheLastGoodFrame) {
  REKON_REQUIRE_DATASET(data, "7scenes_loop_1000");
  rekon::test::TempDir dir;
  constexpr int kFrames = 1000, kFrom = 900, kCut = 50;
  ASSERT_NO_FATAL_FAILURE(runEditedAndWhole(data, dir, kFrames, kFrom, kCut, Edit::CutOut));
  const std::string tracker = readText(dir / "edited_run/tracker_stats.json");
  EXPECT_EQ(jsonInt(tracker, "lost_frames"), 0) << tracker;
  EXPECT_EQ(jsonInt(tracker, "lost_intervals_count"), 0) << tracker;
  EXPECT_NE(readText(dir / "edited_run/tracker.log").find("frame 900: aligned across a gap of 1.70 s"), std::string::npos);
  const std::string mapper = readText(dir / "edited_run/mapper_stats.json");
  EXPECT_EQ(jsonInt(mapper, "frames_fused"), kFrames - kCut) << mapper;

  // The jump across the cut (the last frame before it to the first after), estimated and true.
  const double before_cut = kFrom - 1, after_cut = kFrom + kCut;  // original frame numbers, 30 Hz
  const auto jump = [&](const std::string& path) {
    const Trajectory t = readTumTrajectory(path);
    const int a = nearestInTime(t, before_cut / 30.0, 0.01), b = nearestInTime(t, after_cut / 30.0, 0.01);
    EXPECT_GE(a, 0) << path;
    EXPECT_GE(b, 0) << path;
    return a < 0 || b < 0 ? Pose::Identity() : Pose(t[static_cast<size_t>(a)].pose.inverse() * t[static_cast<size_t>(b)].pose);
  };
  const Pose estimated = jump(dir / "edited_run/trajectory.txt"), truth = jump(data + "/groundtruth.txt");
  EXPECT_GT(truth.translation().norm(), 0.4);  // the cut is a real jump
  EXPECT_LT(translationDistance(estimated, truth), 0.03);
  EXPECT_LT(rotationAngle(estimated, truth) * 180.0 / M_PI, 5.0);

  const double cut = ateOf(data + "/groundtruth.txt", dir / "edited_run/trajectory.txt");
  const double uncut = ateOf(data + "/groundtruth.txt", dir / "whole_run/trajectory.txt");
  EXPECT_GT(uncut, 0.0);
  EXPECT_LT(cut, 1.3 * uncut);
  std::cout << "ATE cut " << cut << " m, uncut " << uncut << " m; jump " << estimated.translation().norm() << " m (true "
            << truth.translation().norm() << " m), off by " << translationDistance(estimated, truth) << " m and "
            << rotationAngle(estimated, truth) * 180.0 / M_PI << " degrees\n";
}

}  // namespace
}  // namespace rekon::tracker
