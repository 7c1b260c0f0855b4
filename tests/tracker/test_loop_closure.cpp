// Loop-closure detection on keyframes rendered from the synthetic room's
// loop (Kinect noise): the end of the loop looks at the start again.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <numbers>
#include <vector>

#include "rekon/tracker/loop_closure.hpp"
#include "synthetic_views.hpp"
#include "test_support.hpp"

namespace rekon::tracker {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

// A keyframe as the tracker makes it, from a rendered frame.
std::shared_ptr<const Keyframe> makeKeyframe(int64_t id, const RgbdFrame& frame, const Intrinsics& k,
                                             const Pose& pose_world, const AlignerParams& p) {
  auto kf = std::make_shared<Keyframe>();
  kf->id = id;
  kf->frame_id = frame.id;
  kf->pose_world = pose_world;
  kf->pyramid.build(frame, k, p.finest_level, p.coarsest_level, p.min_depth, p.max_depth);
  kf->reference = KeyframeReference(kf->pyramid, p);
  return kf;
}

// The odometry constraint the tracker would publish between two keyframes.
OdometryConstraint odometryBetween(const Keyframe& from, const Keyframe& to, const Pose& truth_relative,
                                   const AlignerParams& p) {
  DenseAligner aligner(p);
  const AlignResult r = aligner.align(from.reference, to.pyramid, truth_relative);
  EXPECT_TRUE(r.valid);
  OdometryConstraint c;
  c.from_id = from.id;
  c.to_id = to.id;
  c.relative = r.pose;
  c.information = r.information;
  c.entropy = r.entropy;
  c.valid_pixels = r.valid_pixels;
  return c;
}

// Odometry drift of the loop's end: 8 cm and 3 degrees about the vertical.
Pose drift() {
  Pose d = Pose::Identity();
  d.linear() = Eigen::AngleAxisd(3.0 * kDeg, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  d.translation() = Eigen::Vector3d(0.08, -0.05, 0.0);
  return d;
}

class LoopClosureTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    room_ = new test::RoomViews();
    truth_ = new Trajectory(room_->trajectory(600));
  }
  static void TearDownTestSuite() {
    delete truth_;
    delete room_;
  }
  static inline test::RoomViews* room_ = nullptr;
  static inline Trajectory* truth_ = nullptr;

  TrackerParams params;
  int color_shift_px = 0;  // every rendered keyframe's color moved this far right and down against depth
  const Pose& truthAt(int frame) const { return (*truth_)[static_cast<size_t>(frame)].pose; }
  Pose loopPose(double refine_weight);

  // Adds keyframes rendered at `frames` (consecutive ids from `first_id`),
  // each linked by odometry to the one before, at world poses `offset` x truth.
  void addChain(LoopClosureDetector& d, int64_t first_id, const std::vector<int>& frames,
                const Pose& offset = Pose::Identity()) {
    std::shared_ptr<const Keyframe> prev;
    int prev_frame = 0;
    for (size_t i = 0; i < frames.size(); ++i) {
      const RgbdFrame f = test::colorShifted(room_->render(truthAt(frames[i]), synth::Noise::Kinect, frames[i]),
                                             color_shift_px, color_shift_px);
      auto kf = makeKeyframe(first_id + static_cast<int64_t>(i), f, room_->intrinsics(), offset * truthAt(frames[i]),
                             params.aligner);
      std::optional<OdometryConstraint> odo;
      if (prev) odo = odometryBetween(*prev, *kf, truthAt(prev_frame).inverse() * truthAt(frames[i]), params.aligner);
      d.addKeyframe(kf, odo);
      prev = kf;
      prev_frame = frames[i];
    }
  }
};

TEST_F(LoopClosureTest, TheLoopsEndIsAcceptedAgainstItsStartWithTheTrueRelativePose) {
  LoopClosureDetector d(params);
  addChain(d, 0, {0, 12, 24});
  // The end of the loop (frame 599 is frame 0's pose again), tracked with drift.
  addChain(d, 3, {566, 578, 590}, drift());
  const CandidateCheck c = d.check(0, 5);
  ASSERT_TRUE(c.accepted) << c.reason << " coarse " << c.best_coarse_ratio << " fine " << c.best_fine_ratio;
  const Pose truth = truthAt(0).inverse() * truthAt(590);
  // Kinect-noise keyframes ~10 cm apart align to a few millimetres; 1 cm and
  // 0.5 degree leave room for the noise yet lie far below the 8 cm / 3 degree
  // drift of the initial estimate.
  EXPECT_LT(translationDistance(c.constraint->relative, truth), 0.01);
  EXPECT_LT(rotationAngle(c.constraint->relative, truth) / kDeg, 0.5);
  EXPECT_TRUE(c.constraint->information.allFinite());
}

// While other checks wait (the worker is behind), a check aligns only the
// candidates_when_behind nearest views; with nothing waiting, every candidate.
TEST_F(LoopClosureTest, ACheckBehindOthersTakesOnlyItsNearestCandidates) {
  params.loop.exclude_predecessors = 2;  // keyframes 0-2 are the loop end's candidates
  params.loop.candidates_when_behind = 2;
  LoopClosureDetector d(params);
  addChain(d, 0, {0, 12, 24});
  addChain(d, 3, {566, 578, 590}, drift());
  LoopClosureStats alone, behind;
  d.detect(5, alone);
  d.detect(5, behind, /*behind=*/true);
  EXPECT_EQ(alone.candidates, 3);
  EXPECT_EQ(alone.candidates_skipped, 0);
  EXPECT_EQ(alone.checks_behind, 0);
  EXPECT_EQ(behind.candidates, 2);
  EXPECT_EQ(behind.candidates_skipped, 1);
  EXPECT_EQ(behind.checks_behind, 1);
  EXPECT_GE(behind.accepted, 1) << "the nearest views are the ones kept: the loop is still found";
}

// Issue 26: the keyframes beyond tracker.keyframes_in_memory wait on disk
// and are read back for a check; the check is the same, bit for bit (the
// finest level is stored, the coarser levels and the reference rebuilt by
// the same code), and the files go with the cache.
TEST_F(LoopClosureTest, CandidatesOnDiskGiveTheSameLoopAsCandidatesInMemory) {
  LoopClosureDetector all(params);
  addChain(all, 0, {0, 12, 24});
  addChain(all, 3, {566, 578, 590}, drift());
  const CandidateCheck expected = all.check(0, 5);
  ASSERT_TRUE(expected.accepted) << expected.reason;

  rekon::test::TempDir dir;
  params.memory.keyframes_in_memory = 2;
  params.memory.spill_dir = dir / "spill";
  auto cache = std::make_shared<KeyframeCache>(params);
  {
    LoopClosureDetector bounded(params, cache);
    addChain(bounded, 0, {0, 12, 24});
    addChain(bounded, 3, {566, 578, 590}, drift());
    const KeyframeCacheStats before = cache->stats();
    EXPECT_EQ(before.keyframes, 6);
    EXPECT_EQ(before.resident, 2);
    EXPECT_EQ(before.spilled, 4);  // each written once
    const CandidateCheck c = bounded.check(0, 5);
    ASSERT_TRUE(c.accepted) << c.reason;
    EXPECT_EQ(c.constraint->relative.matrix(), expected.constraint->relative.matrix());
    EXPECT_EQ(c.constraint->information, expected.constraint->information);
    EXPECT_GE(cache->stats().loaded, 1);
    EXPECT_LE(cache->stats().resident, 2);
    EXPECT_TRUE(std::filesystem::exists(dir / "spill/tracker"));
  }
  cache.reset();
  EXPECT_FALSE(std::filesystem::exists(dir / "spill")) << "the cache removes its files and the folder it made";
}

// A tracker killed while keyframes were on disk leaves its automatic spill
// folder; the next tracker to spill removes the folders of trackers that are
// gone, and no other.
TEST_F(LoopClosureTest, AutomaticSpillFoldersOfTrackersThatAreGoneAreRemoved) {
  rekon::test::TempDir tmp;
  const pid_t child = fork();
  if (child == 0) _exit(0);
  ASSERT_GT(child, 0);
  waitpid(child, nullptr, 0);  // its pid now names no process
  const std::string gone = tmp / ("rekon_tracker_" + std::to_string(child) + ".spill");
  const std::string alive = tmp / "rekon_tracker_1.spill";  // init: always running
  const std::string other = tmp / "rekon_tracker_notes.txt";
  for (const std::string& d : {gone, alive}) std::filesystem::create_directories(d + "/tracker");
  std::ofstream(gone + "/tracker/dvo_000000.rkd") << "left by a killed tracker";
  std::ofstream(other) << "not a spill folder";
  const char* old_tmpdir = std::getenv("TMPDIR");
  const std::string saved = old_tmpdir ? old_tmpdir : "";
  setenv("TMPDIR", tmp.path().c_str(), 1);
  params.memory.keyframes_in_memory = 2;  // spill_dir "auto"
  {
    LoopClosureDetector d(params);
    addChain(d, 0, {0, 12, 24});  // the third spills one
  }
  if (old_tmpdir) setenv("TMPDIR", saved.c_str(), 1);
  else unsetenv("TMPDIR");
  EXPECT_FALSE(std::filesystem::exists(gone));
  EXPECT_TRUE(std::filesystem::exists(alive));
  EXPECT_TRUE(std::filesystem::exists(other));
  EXPECT_FALSE(std::filesystem::exists(tmp / ("rekon_tracker_" + std::to_string(getpid()) + ".spill")))
      << "its own folder goes with the cache";
}

// The loop pose of the room's end (frames 550-574) against its start, with
// the accepted alignments refined at `refine_weight` (1: not refined).
Pose LoopClosureTest::loopPose(double refine_weight) {
  params.loop.refine_photometric_weight = refine_weight;
  LoopClosureDetector d(params);
  addChain(d, 0, {0, 12, 24});
  addChain(d, 3, {550, 562, 574}, drift());
  const CandidateCheck c = d.check(0, 5);
  EXPECT_TRUE(c.accepted) << c.reason << " coarse " << c.best_coarse_ratio << " fine " << c.best_fine_ratio;
  return c.accepted ? c.constraint->relative : Pose::Identity();
}

TEST_F(LoopClosureTest, ColorNotRegisteredToDepthBiasesTheLoopAndTheRefinementLowersTheBias) {
  const Pose truth = truthAt(0).inverse() * truthAt(574);
  const double refine = LoopClosureParams::kDefaultRefinePhotometricWeight;
  // Registered color: both sub-millimetre (0.06 / 0.09 mm when written).
  color_shift_px = 0;
  EXPECT_LT(translationDistance(loopPose(1.0), truth), 5e-4);
  EXPECT_LT(translationDistance(loopPose(refine), truth), 5e-4);
  // Color 3 pixels off depth in every keyframe (7-Scenes: a few pixels at
  // edges): when written 2.49 mm / 0.098 deg full, 1.79 mm / 0.043 deg refined.
  color_shift_px = 3;
  const Pose full = loopPose(1.0), refined = loopPose(refine);
  EXPECT_GT(translationDistance(full, truth), 1.5e-3);  // the bias this test is about is there
  EXPECT_LT(translationDistance(refined, truth), 0.85 * translationDistance(full, truth));
  EXPECT_LT(rotationAngle(refined, truth), 0.6 * rotationAngle(full, truth));
}

TEST_F(LoopClosureTest, CandidatesAreEarlierKeyframesInTheSphereWithoutTheExcludedPredecessors) {
  params.loop.exclude_predecessors = 2;
  LoopClosureDetector d(params);
  // Start of the loop, its far side (about 2 m away), and its end.
  addChain(d, 0, {0, 12});
  addChain(d, 2, {300});
  addChain(d, 3, {566, 578, 590});
  const std::vector<int64_t> ids = d.candidates(5);
  // 0 and 1 are within 1 m of frame 590; 2 is across the room; 3 and 4 are
  // the two excluded predecessors.
  ASSERT_EQ(ids.size(), 2u);
  EXPECT_EQ(std::count(ids.begin(), ids.end(), 0), 1);
  EXPECT_EQ(std::count(ids.begin(), ids.end(), 1), 1);
}

// The tracker checks on every core once the stream has ended: the same loops
// and counts, bit for bit, as on one thread (each candidate is checked on its
// own; the database is read before, in candidate order).
TEST_F(LoopClosureTest, DetectOnSeveralThreadsFindsWhatOneThreadFinds) {
  params.loop.exclude_predecessors = 1;
  std::vector<LoopConstraint> found[2];
  LoopClosureStats stats[2];
  for (int run = 0; run < 2; ++run) {
    LoopClosureDetector d(params);
    d.setThreads(run == 0 ? 1 : 3);
    addChain(d, 0, {0, 12, 24});
    addChain(d, 3, {300});  // across the room: no candidate
    addChain(d, 4, {566, 578, 590}, drift());
    found[run] = d.detect(6, stats[run]);
  }
  EXPECT_EQ(stats[1].candidates, stats[0].candidates);
  EXPECT_EQ(stats[1].accepted, stats[0].accepted);
  EXPECT_EQ(stats[1].rejected, stats[0].rejected);
  ASSERT_GE(found[0].size(), 2u) << "the loop's start is found from its end";
  ASSERT_EQ(found[1].size(), found[0].size());
  for (size_t i = 0; i < found[0].size(); ++i) {
    EXPECT_EQ(found[1][i].from_id, found[0][i].from_id);
    EXPECT_EQ(found[1][i].relative.matrix(), found[0][i].relative.matrix());
    EXPECT_EQ(found[1][i].information, found[0][i].information);
  }
}

TEST_F(LoopClosureTest, AViewOfADifferentPlaceIsRejectedEvenWhenTheEstimatePutsItClose) {
  params.loop.exclude_predecessors = 1;  // keyframe 0 is only three keyframes back
  LoopClosureDetector d(params);
  addChain(d, 0, {0, 12});
  // Frames 288 and 300 look at the far side of the room; odometry gone wrong
  // claims they were taken where frame 0 was.
  const Pose wrong = truthAt(0) * truthAt(288).inverse();
  addChain(d, 2, {288, 300}, wrong);
  ASSERT_LT(translationDistance(d.estimate(3), truthAt(0)), 0.5);
  const std::vector<int64_t> ids = d.candidates(3);
  ASSERT_NE(std::find(ids.begin(), ids.end(), 0), ids.end());
  const CandidateCheck c = d.check(0, 3);
  EXPECT_FALSE(c.accepted) << "coarse " << c.best_coarse_ratio << " fine " << c.best_fine_ratio;
}

TEST_F(LoopClosureTest, AGraphUpdateMovesTheEstimateAndAnOlderOneIsIgnored) {
  LoopClosureDetector d(params);
  addChain(d, 0, {0, 12});
  Pose moved = truthAt(12);
  moved.translation() += Eigen::Vector3d(0.0, 0.0, 0.3);
  d.updateGraph(2, {{0, truthAt(0)}, {1, moved}});
  EXPECT_LT(translationDistance(d.estimate(1), moved), 1e-9);
  d.updateGraph(1, {{0, truthAt(0)}, {1, truthAt(12)}});  // older: ignored
  EXPECT_EQ(d.graphVersion(), 2);
  EXPECT_LT(translationDistance(d.estimate(1), moved), 1e-9);
}

// A loop pose aligned both ways round: `forward` the new keyframe in the
// candidate, `backward` the candidate in the new keyframe.
AlignResult aligned(const Pose& pose, double information) {
  AlignResult r;
  r.pose = pose;
  r.information = information * Matrix6d::Identity();
  r.valid = true;
  return r;
}

TEST(LoopBothDirections, AgreeingDirectionsGiveTheirCommonPose) {
  Pose t = Pose::Identity();
  t.linear() = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  t.translation() = Eigen::Vector3d(0.3, -0.1, 0.2);
  const Pose mean = bothDirections(aligned(t, 1e4), aligned(t.inverse(), 1e4));
  EXPECT_LT(translationDistance(mean, t), 1e-9);
  EXPECT_LT(rotationAngle(mean, t), 1e-9);
}

TEST(LoopBothDirections, TheMeanIsTheMidpoint) {
  Pose t = Pose::Identity();
  t.translation() = Eigen::Vector3d(0.3, -0.1, 0.2);
  Pose other = t;
  other.translation().x() += 0.02;  // the backward alignment says 2 cm further along x
  other.linear() = Eigen::AngleAxisd(0.01, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  // Halfway: 1 cm along x (to 1e-4: the half rotation bends the SE(3) path by
  // about 0.005 rad x 2 cm) and 0.005 rad about z, whatever the informations.
  for (const double backward_information : {1e2, 1e4, 1e6}) {
    const Pose mid = bothDirections(aligned(t, 1e4), aligned(other.inverse(), backward_information));
    EXPECT_NEAR(mid.translation().x(), 0.31, 1e-4);
    EXPECT_NEAR(rotationAngle(mid, t), 0.005, 1e-9);
    EXPECT_NEAR(rotationAngle(mid, other), 0.005, 1e-9);
  }
}

// Keyframes 10 m apart: no candidates, so a check aligns nothing.
std::shared_ptr<const Keyframe> farApartKeyframe(int64_t id) {
  auto kf = std::make_shared<Keyframe>();
  kf->id = id;
  kf->pose_world.translation() = Eigen::Vector3d(10.0 * static_cast<double>(id), 0.0, 0.0);
  return kf;
}

TEST(LoopClosureWorker, AFullQueueDropsTheOldestChecks) {
  TrackerParams params;
  params.loop.queue_capacity = 2;
  int accepted = 0;
  LoopClosureWorker worker(params, [&](const LoopConstraint&) { ++accepted; }, /*start=*/false);
  for (int64_t id = 0; id < 5; ++id) worker.submit(farApartKeyframe(id), std::nullopt);
  // Five submitted into room for two: the checks of keyframes 0, 1, 2 went.
  EXPECT_EQ(worker.stats().checks_dropped, 3);
  worker.start();
  ASSERT_TRUE(worker.waitUntilDrained(10000));
  EXPECT_EQ(worker.checkedKeyframes(), (std::vector<int64_t>{3, 4}));
  EXPECT_EQ(worker.stats().keyframes_checked, 2);
  EXPECT_EQ(accepted, 0);
}


// A check is behind while kBehindWhenWaiting or more others wait: of ten
// queued before the worker starts, the first two (9 and 8 waiting). With
// when_behind kFewer they take candidates_when_behind; with kHold (the
// service holds the frames back instead) every candidate.
TEST(LoopClosureWorker, ChecksWithManyOthersWaitingAreBehind) {
  for (const auto mode : {LoopClosureParams::WhenBehind::kFewer, LoopClosureParams::WhenBehind::kHold}) {
    TrackerParams params;
    params.loop.when_behind = mode;
    LoopClosureWorker worker(params, [](const LoopConstraint&) {}, /*start=*/false);
    for (int64_t id = 0; id < 10; ++id) {
      EXPECT_EQ(worker.behind(), id >= LoopClosureWorker::kBehindWhenWaiting);
      worker.submit(farApartKeyframe(id), std::nullopt);
    }
    EXPECT_TRUE(worker.behind());
    worker.start();
    ASSERT_TRUE(worker.waitUntilDrained(10000));
    EXPECT_FALSE(worker.behind());
    static_assert(LoopClosureWorker::kBehindWhenWaiting == 8);
    EXPECT_EQ(worker.stats().checks_behind, mode == LoopClosureParams::WhenBehind::kFewer ? 2 : 0);
    EXPECT_EQ(worker.stats().keyframes_checked, 10);
  }
}

// A stalled worker (never started here) while keyframes keep coming: before,
// only the checks were capped and every keyframe stayed queued (a job each,
// holding its images), without limit. Now at most queue_capacity checks and
// queue_capacity candidates wait; the oldest candidates are the ones dropped.
TEST(LoopClosureWorker, AStalledWorkerHoldsAtMostTwiceTheQueueCapacityAndDropsTheOldestCandidates) {
  TrackerParams params;
  params.loop.queue_capacity = 2;
  LoopClosureWorker worker(params, [](const LoopConstraint&) {}, /*start=*/false);
  std::vector<std::weak_ptr<const Keyframe>> submitted;
  for (int64_t id = 0; id < 10; ++id) {
    auto kf = farApartKeyframe(id);
    submitted.push_back(kf);
    worker.submit(std::move(kf), std::nullopt);
  }
  std::vector<int64_t> held;  // keyframes the queue still holds
  for (size_t id = 0; id < submitted.size(); ++id) {
    if (!submitted[id].expired()) held.push_back(static_cast<int64_t>(id));
  }
  // Checks of 8 and 9 wait, 6 and 7 wait as candidates; 0-5 were let go.
  EXPECT_EQ(held, (std::vector<int64_t>{6, 7, 8, 9}));
  EXPECT_EQ(worker.stats().checks_dropped, 8);
  EXPECT_EQ(worker.stats().candidates_dropped, 6);
  worker.start();
  ASSERT_TRUE(worker.waitUntilDrained(10000));
  EXPECT_EQ(worker.checkedKeyframes(), (std::vector<int64_t>{8, 9}));
}

}  // namespace
}  // namespace rekon::tracker
