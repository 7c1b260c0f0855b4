// The tracker on rendered sequences: keyframes, lost frames and recovery.
#include <gtest/gtest.h>

#include <numbers>

#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"
#include "rekon/slam_bench/trajectory_metrics.hpp"
#include "rekon/tracker/tracker.hpp"
#include "synthetic_views.hpp"

namespace rekon::tracker {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

class TrackerTest : public ::testing::Test {
 protected:
  test::RoomViews room;
  Trajectory truth = room.trajectory(12);
  RgbdFrame frameAt(int i) const { return room.render(truth[i].pose, synth::Noise::None, i); }
  // The tracker puts the first keyframe at the origin.
  Pose truthFromFirst(int i) const { return truth[0].pose.inverse() * truth[i].pose; }
  double errorM(const TrackResult& r, int i) const { return translationDistance(r.pose_world, truthFromFirst(i)); }

  static void expectSafePose(const TrackResult& r) {
    EXPECT_TRUE(isValidPose(r.pose_in_keyframe));
    EXPECT_TRUE(isValidPose(r.pose_world));
    EXPECT_TRUE(r.covariance.allFinite());
  }

  // Tracks frames 0..3, then `bad` as frame 4, then frames 5 and 6; expects
  // frame 4 lost for `reason` and frames 5 and 6 back on track.
  void expectLostThenRecovered(const RgbdFrame& bad, LostReason reason) {
    Tracker tracker;
    for (int i = 0; i < 4; ++i) ASSERT_EQ(tracker.track(frameAt(i), room.intrinsics()).state, TrackingState::Ok);
    const TrackResult lost = tracker.track(bad, room.intrinsics());
    EXPECT_EQ(lost.state, TrackingState::Lost);
    if (reason != LostReason::None) {
      EXPECT_EQ(lost.lost_reason, reason) << toString(lost.lost_reason);
    }
    expectSafePose(lost);
    // The last good pose is published for the lost frame.
    EXPECT_LT(errorM(lost, 3), 0.003);
    for (int i = 5; i < 7; ++i) {
      const TrackResult r = tracker.track(frameAt(i), room.intrinsics());
      EXPECT_EQ(r.state, TrackingState::Ok) << "frame " << i;
      expectSafePose(r);
      // Re-initialised from the last good keyframe: back within 3 mm.
      EXPECT_LT(errorM(r, i), 0.003) << "frame " << i;
    }
  }
};

TEST_F(TrackerTest, FirstFrameStartsKeyframeZeroAtTheOrigin) {
  Tracker tracker;
  const TrackResult r = tracker.track(frameAt(0), room.intrinsics());
  EXPECT_EQ(r.state, TrackingState::Ok);
  EXPECT_TRUE(r.new_keyframe);
  EXPECT_EQ(r.keyframe_id, 0);
  EXPECT_FALSE(r.odometry.has_value());
  EXPECT_TRUE(r.pose_world.isApprox(Pose::Identity()));
}

TEST_F(TrackerTest, TracksARenderedSequenceWithin2mm) {
  Tracker tracker;
  for (int i = 0; i < 10; ++i) {
    const TrackResult r = tracker.track(frameAt(i), room.intrinsics());
    ASSERT_EQ(r.state, TrackingState::Ok) << "frame " << i << ": " << toString(r.lost_reason);
    // Noise-free frames: the alignment error is far below a millimetre per
    // frame, so ten frames stay within 2 mm.
    EXPECT_LT(errorM(r, i), 0.002) << "frame " << i;
  }
}

TEST_F(TrackerTest, EmptyDepthIsLostWithAFinitePoseAndTrackingRecovers) {
  expectLostThenRecovered(test::withoutDepth(frameAt(4)), LostReason::NoDepth);
}

TEST_F(TrackerTest, BlackImageIsLostWithAFinitePoseAndTrackingRecovers) {
  expectLostThenRecovered(test::blackImage(frameAt(4)), LostReason::BlackImage);
}

TEST_F(TrackerTest, JumpBeyondTheConvergenceBasinIsLostAndTrackingRecovers) {
  // One frame from 1.2 m away, turned 70 degrees: no alignment from the
  // constant-velocity prediction can reach it.
  Pose jump = Pose::Identity();
  jump.linear() = Eigen::AngleAxisd(70 * kDeg, Eigen::Vector3d::UnitY()).toRotationMatrix();
  jump.translation() = Eigen::Vector3d(0.8, 0.1, -0.9);
  RgbdFrame far = room.render(truth[4].pose * jump, synth::Noise::None, 4);
  expectLostThenRecovered(far, LostReason::None);
}

TEST_F(TrackerTest, TooManyLostFramesInARowRestartAtTheLastGoodPose) {
  TrackerParams p;
  p.lost.max_lost_frames = 2;
  Tracker tracker(p);
  for (int i = 0; i < 3; ++i) tracker.track(frameAt(i), room.intrinsics());
  Pose jump = Pose::Identity();
  jump.linear() = Eigen::AngleAxisd(90 * kDeg, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const RgbdFrame far = room.render(truth[3].pose * jump, synth::Noise::None, 3);
  const TrackResult first = tracker.track(far, room.intrinsics());
  EXPECT_EQ(first.state, TrackingState::Lost);
  EXPECT_FALSE(first.new_keyframe);
  const TrackResult second = tracker.track(far, room.intrinsics());
  EXPECT_EQ(second.state, TrackingState::Lost);
  EXPECT_TRUE(second.new_keyframe);
  EXPECT_TRUE(second.keyframe_reset);
  EXPECT_FALSE(second.odometry.has_value());  // nothing links it to the old keyframe
  EXPECT_EQ(second.keyframe_id, 1);
  EXPECT_LT(errorM(second, 2), 0.003);  // started at the last good pose
  EXPECT_EQ(tracker.track(far, room.intrinsics()).state, TrackingState::Ok);
}

TEST(TrackerParams, DefaultConfigGivesTheNamedDefaults) {
  const TrackerParams p = trackerParamsFromConfig(Config::load());
  const TrackerParams d;
  EXPECT_EQ(p.aligner.finest_level, d.aligner.finest_level);
  EXPECT_EQ(p.aligner.coarsest_level, d.aligner.coarsest_level);
  EXPECT_EQ(p.aligner.max_iterations, d.aligner.max_iterations);
  EXPECT_DOUBLE_EQ(p.aligner.convergence_step, d.aligner.convergence_step);
  EXPECT_DOUBLE_EQ(p.aligner.t_dof, d.aligner.t_dof);
  EXPECT_DOUBLE_EQ(p.aligner.min_gradient, d.aligner.min_gradient);
  EXPECT_EQ(p.aligner.max_pixels_per_level, d.aligner.max_pixels_per_level);
  EXPECT_DOUBLE_EQ(p.aligner.min_depth, d.aligner.min_depth);
  EXPECT_DOUBLE_EQ(p.aligner.max_depth, d.aligner.max_depth);
  EXPECT_DOUBLE_EQ(p.aligner.max_depth_step, d.aligner.max_depth_step);
  EXPECT_EQ(p.aligner.min_valid_pixels, d.aligner.min_valid_pixels);
  EXPECT_EQ(p.aligner.use_depth, d.aligner.use_depth);
  EXPECT_EQ(p.keyframe.criterion, d.keyframe.criterion);
  EXPECT_DOUBLE_EQ(p.keyframe.entropy_ratio, d.keyframe.entropy_ratio);
  EXPECT_DOUBLE_EQ(p.keyframe.max_translation, d.keyframe.max_translation);
  EXPECT_DOUBLE_EQ(p.keyframe.max_rotation_deg, d.keyframe.max_rotation_deg);
  EXPECT_EQ(p.keyframe.reuse, d.keyframe.reuse);
  EXPECT_DOUBLE_EQ(p.keyframe.reuse_radius, d.keyframe.reuse_radius);
  EXPECT_DOUBLE_EQ(p.keyframe.reuse_angle_deg, d.keyframe.reuse_angle_deg);
  EXPECT_EQ(p.keyframe.reuse_candidates, d.keyframe.reuse_candidates);
  EXPECT_EQ(p.keyframe.reuse_exclude_recent, d.keyframe.reuse_exclude_recent);
  EXPECT_DOUBLE_EQ(p.lost.min_valid_depth_fraction, d.lost.min_valid_depth_fraction);
  EXPECT_DOUBLE_EQ(p.lost.min_mean_intensity, d.lost.min_mean_intensity);
  EXPECT_DOUBLE_EQ(p.lost.min_overlap, d.lost.min_overlap);
  EXPECT_DOUBLE_EQ(p.lost.max_frame_translation, d.lost.max_frame_translation);
  EXPECT_DOUBLE_EQ(p.lost.max_frame_rotation_deg, d.lost.max_frame_rotation_deg);
  EXPECT_DOUBLE_EQ(p.lost.max_intensity_sigma, d.lost.max_intensity_sigma);
  EXPECT_DOUBLE_EQ(p.lost.max_depth_sigma, d.lost.max_depth_sigma);
  EXPECT_DOUBLE_EQ(p.lost.residual_entropy_ratio, d.lost.residual_entropy_ratio);
  EXPECT_EQ(p.lost.max_lost_frames, d.lost.max_lost_frames);
  EXPECT_DOUBLE_EQ(p.loop.refine_photometric_weight, d.loop.refine_photometric_weight);
  EXPECT_EQ(p.aligner.gap_coarsest_level, d.aligner.gap_coarsest_level);
  EXPECT_DOUBLE_EQ(p.aligner.gap_coarse_s, d.aligner.gap_coarse_s);
  // A run bounds the keyframes in memory; params built in code (tests, benches) keep them all.
  EXPECT_GT(p.memory.keyframes_in_memory, 0);
  EXPECT_EQ(d.memory.keyframes_in_memory, 0);
}

TEST(TrackerParams, OutOfRangeValueIsAnErrorNamingTheKey) {
  try {
    trackerParamsFromConfig(Config::load("", {"tracker.coarsest_level=0", "tracker.finest_level=1"}));
    FAIL() << "coarsest below finest was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("tracker.coarsest_level"), std::string::npos) << e.what();
  }
  EXPECT_THROW(trackerParamsFromConfig(Config::load("", {"tracker.keyframe_criterion=sometimes"})), Error);
  EXPECT_THROW(trackerParamsFromConfig(Config::load("", {"tracker.loop_refine_photometric_weight=1.5"})), Error);
  EXPECT_THROW(trackerParamsFromConfig(Config::load("", {"tracker.gap_coarsest_level=2"})), Error);  // below coarsest
  EXPECT_THROW(trackerParamsFromConfig(Config::load("", {"tracker.keyframes_in_memory=1"})), Error);
  try {
    trackerParamsFromConfig(Config::load("", {"tracker.keyframe_reuse_radius=0"}));
    FAIL() << "a reuse radius of 0 was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("tracker.keyframe_reuse_radius"), std::string::npos) << e.what();
  }
  EXPECT_THROW(trackerParamsFromConfig(Config::load("", {"tracker.keyframe_reuse_candidates=0"})), Error);
}

// Keyframe selection on the room's loop with Kinect-like noise: 150 frames
// (5 s, 1.6 m, about 90 degrees of turning).
TEST(TrackerKeyframes, SelectionFiresAtASensibleRateOnTheRoomAndChainsConstraints) {
  test::RoomViews room;
  const Trajectory truth = room.trajectory(150);
  Tracker tracker;
  Trajectory estimate;
  int keyframes = 0, lost = 0;
  int64_t previous_keyframe = -1;
  for (int i = 0; i < static_cast<int>(truth.size()); ++i) {
    const TrackResult r = tracker.track(room.render(truth[i].pose, synth::Noise::Kinect, i), room.intrinsics());
    lost += r.state == TrackingState::Lost;
    if (r.new_keyframe) {
      ++keyframes;
      if (r.odometry) {
        EXPECT_EQ(r.odometry->from_id, previous_keyframe);
        EXPECT_EQ(r.odometry->to_id, r.keyframe_id);
        EXPECT_EQ(Eigen::LLT<Matrix6d>(r.odometry->information).info(), Eigen::Success);
      }
      previous_keyframe = r.keyframe_id;
    }
    estimate.push_back({truth[i].timestamp, r.pose_world});
  }
  EXPECT_EQ(lost, 0);
  // The distance limit alone forces a keyframe every 0.2 m: 7 or 8 on this
  // 1.6 m (measured: 8). The entropy ratio may add some, but a keyframe
  // every frame or two would defeat its purpose (at most 50: one per 3 frames).
  EXPECT_GE(keyframes, 6);
  EXPECT_LE(keyframes, 50);
  const auto errors = slam_bench::compareTrajectories(estimate, truth);
  // Exact geometry and white sensor noise, rendered with fixed seeds: measured
  // 0.1876 mm in 3 runs, identical to the last digit (no run-to-run noise).
  // 0.25 mm leaves a third for another compiler or CPU's rounding; a tracker
  // 1.5x worse fails.
  EXPECT_LT(errors.ate_rmse_m, 0.00025);
  RecordProperty("keyframes", keyframes);
  std::printf("room 150 frames: keyframes=%d ate_mm=%.4f rpe_mm_per_s=%.4f\n", keyframes, 1e3 * errors.ate_rmse_m,
              1e3 * errors.rpe_trans_m_per_s);
}

// The entropy ratio on its own: with the distance limits out of reach, only
// H(kf,t)/H(kf,kf+1) < 0.91 can select keyframes as the view drifts away from
// the keyframe (and that keeps tracking alive); with the distance criterion
// and the same limits, none is selected and tracking is eventually lost.
TEST(TrackerKeyframes, EntropyRatioAloneSelectsKeyframesAsTheViewDrifts) {
  test::RoomViews room;
  const Trajectory truth = room.trajectory(300);
  std::vector<RgbdFrame> frames;  // every third frame: 3.2 m in 100 frames
  for (int i = 0; i < 300; i += 3) frames.push_back(room.render(truth[i].pose, synth::Noise::Kinect, i));
  struct Outcome {
    int selected = 0, lost = 0;
    int first_selected = -1, first_lost = -1;  // indices into frames
    std::vector<double> ratios_at_selection;
  };
  auto run = [&](const std::string& criterion) {
    TrackerParams p;
    p.keyframe.criterion = criterion;
    p.keyframe.max_translation = 100.0;
    p.keyframe.max_rotation_deg = 180.0;
    Tracker tracker(p);
    Outcome o;
    for (int i = 0; i < static_cast<int>(frames.size()); ++i) {
      const TrackResult r = tracker.track(frames[i], room.intrinsics());
      if (r.state == TrackingState::Lost) {
        if (o.lost++ == 0) o.first_lost = i;
      }
      if (r.new_keyframe && r.odometry) {  // selected, not the first nor a restart after losing track
        if (o.selected++ == 0) o.first_selected = i;
        o.ratios_at_selection.push_back(r.entropy_ratio);
      }
    }
    std::printf("%s: selected=%d (first at %d) lost=%d (first at %d)\n", criterion.c_str(), o.selected, o.first_selected,
                o.lost, o.first_lost);
    return o;
  };
  const Outcome entropy = run("entropy_ratio");
  EXPECT_EQ(entropy.lost, 0);
  // Measured: one keyframe about every 0.45 m, 6 on this path, the first at
  // frame 9 (the same in 3 runs); 5..8 leaves a keyframe either way for
  // another machine's rounding.
  EXPECT_GE(entropy.selected, 5);
  EXPECT_LE(entropy.selected, 8);
  for (double ratio : entropy.ratios_at_selection) EXPECT_LT(ratio, 0.91);
  const Outcome distance = run("distance");
  // The distance criterion must not consult the entropy ratio (its limits are out of reach).
  EXPECT_EQ(distance.selected, 0);
  // Without those keyframes the same frames lose track (measured: 55 of 100
  // lost, the first at frame 21), and only after the entropy ratio had
  // already started a new keyframe (frame 9): it anticipates the loss.
  EXPECT_GT(distance.lost, 0);
  EXPECT_LT(entropy.first_selected, distance.first_lost);
  EXPECT_GE(entropy.first_selected, 0);
}

// Frames dropped or skipped (a live camera on a starved machine): every
// `stride`-th frame of the room's 300 with Kinect-like noise, so the camera
// moves `stride` periods between the frames the tracker sees.
double ateOnEveryNthFrame(int stride, const TrackerParams& params) {
  test::RoomViews room;
  const Trajectory truth = room.trajectory(300);
  Tracker tracker(params);
  Trajectory estimate, seen;
  for (int i = 0; i < static_cast<int>(truth.size()); i += stride) {
    const TrackResult r = tracker.track(room.render(truth[i].pose, synth::Noise::Kinect, i), room.intrinsics());
    if (r.state != TrackingState::Ok) continue;
    estimate.push_back({truth[i].timestamp, r.pose_world});
    seen.push_back(truth[i]);
  }
  EXPECT_GT(estimate.size(), 300u / stride * 9 / 10) << "stride " << stride << ": most frames tracked";
  const double ate = slam_bench::compareTrajectories(estimate, seen).ate_rmse_m;
  std::printf("every %dth frame, gap level %d: ate_mm=%.3f\n", stride, params.aligner.gap_coarsest_level, 1e3 * ate);
  return ate;
}

TEST(TrackerGaps, FramesAfterAGapStartOnACoarserLevelAndStayOnTrack) {
  TrackerParams without_gap_level;
  without_gap_level.aligner.gap_coarsest_level = without_gap_level.aligner.coarsest_level;
  for (const int stride : {6, 9}) {
    // Measured (every 6th / 9th frame, fixed seeds): 0.153 / 0.175 mm from
    // level 4 after a gap, 61.8 / 100.6 mm from level 3 throughout. 2 mm is
    // ten times the first, 10 mm a sixth of the second.
    EXPECT_LT(ateOnEveryNthFrame(stride, TrackerParams{}), 0.002) << "stride " << stride;
    EXPECT_GT(ateOnEveryNthFrame(stride, without_gap_level), 0.01) << "stride " << stride << ": the case the level is for";
  }
}

// A gap in the data of over tracker.lost_max_gap_s (1 s): frames missing, the
// camera moved on 0.3-0.5 m and 18-30 degrees, tracking did not fail. Every
// 2nd frame of the room with Kinect-like noise, the frames after `start`
// for `gap_s` left out; the frame after the gap is aligned to the last good
// frame across the gap and becomes a keyframe (an odometry constraint, no
// loss, no restart). The first case is the live run of issue 29 whose one
// 0.54 s decode left the tracker frames 0, 6, then 46.
TEST(TrackerGaps, AGapOfOverASecondIsBridgedFromTheLastGoodFrame) {
  test::RoomViews room;
  const Trajectory truth = room.trajectory(200);
  std::vector<RgbdFrame> frames;
  for (int i = 0; i < 200; i += 2) frames.push_back(room.render(truth[i].pose, synth::Noise::Kinect, i));
  for (const auto& [start, gap_s] : {std::pair{6, 1.3}, std::pair{30, 1.5}, std::pair{120, 1.1}}) {
    SCOPED_TRACE("gap after frame " + std::to_string(start) + " of " + std::to_string(gap_s) + " s");
    Tracker tracker;
    Trajectory estimate, seen;
    int lost = 0, bridged = 0;
    const double t0 = truth[start].timestamp;
    for (const RgbdFrame& f : frames) {
      if (f.timestamp > t0 && f.timestamp < t0 + gap_s) continue;
      const TrackResult r = tracker.track(f, room.intrinsics());
      EXPECT_FALSE(r.keyframe_reset) << "frame " << f.id;
      if (r.state != TrackingState::Ok) {
        ++lost;
        continue;
      }
      if (f.timestamp > t0 && bridged++ == 0) {
        EXPECT_TRUE(r.new_keyframe);
        EXPECT_TRUE(r.odometry.has_value()) << "the gap is spanned by odometry";
        EXPECT_FALSE(r.relocalised_from.has_value());
      }
      estimate.push_back({f.timestamp, r.pose_world});
      seen.push_back(truth[f.id]);
    }
    const double ate = slam_bench::compareTrajectories(estimate, seen).ate_rmse_m;
    std::printf("gap after frame %d of %.1f s: lost=%d ate_mm=%.3f\n", start, gap_s, lost, 1e3 * ate);
    EXPECT_EQ(lost, 0);
    // Measured: 0.139 / 0.186 / 0.130 mm, no frame lost. Before the frame
    // after the gap was aligned across it: 30 / 30 / 23 frames lost (the
    // keyframes overlap the far view too little for relocalisation to
    // validate), the first two restarted at the last good pose, 276 / 464 mm
    // (the third relocalised 23 frames on, 0.112 mm). 2 mm is over ten times
    // the measured.
    EXPECT_LT(ate, 0.002);
  }
}

}  // namespace
}  // namespace rekon::tracker
