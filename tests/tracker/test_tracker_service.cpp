// rekon-tracker as a process: the player's frames in, odometry out (in a
// private network namespace, so the bus meets no other test).
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "rekon/common/pose.hpp"
#include "rekon/slam_bench/trajectory_metrics.hpp"
#include "rekon/synth/synth.hpp"
#include "test_support.hpp"

namespace rekon::tracker {
namespace {

TEST(TrackerService, TracksEveryFrameThePlayerSendsAndWritesTheOdometry) {
  const std::string in_netns = rekon::test::sourceDir() + "/tests/support/in_netns.sh";
  if (rekon::test::runCommand(in_netns + " true") != 0) GTEST_SKIP() << "cannot create a network namespace (unshare -n)";
  rekon::test::TempDir dir;
  synth::SequenceOptions sequence;
  sequence.scene = "room";
  sequence.frames = 20;
  synth::writeSequence(sequence, dir / "room");

  std::string out;
  const int rc = rekon::test::runCommand(in_netns + " " + rekon::test::binDir() + "/rekon run --dataset " + (dir / "room") +
                                      " --out " + (dir / "out") +
                                      " --set 'run.services=[player,tracker]' --set 'player.wait_for=[tracker]'",
                                  &out);
  ASSERT_EQ(rc, 0) << out;
  std::ifstream stats_file(dir / "out/tracker_stats.json");
  std::stringstream stats;
  stats << stats_file.rdbuf();
  EXPECT_NE(stats.str().find("\"frames\": 20"), std::string::npos) << stats.str();
  EXPECT_NE(stats.str().find("\"lost_frames\": 0"), std::string::npos) << stats.str();
  const Trajectory odometry = readTumTrajectory(dir / "out/odometry.txt");
  ASSERT_EQ(odometry.size(), 20u);
  const auto errors = slam_bench::compareTrajectories(odometry, readTumTrajectory(dir / "room/groundtruth.txt"));
  // The same frames tracked in-process stay far below a millimetre; 5 mm
  // catches frames lost, reordered or mis-decoded on the way.
  EXPECT_LT(errors.ate_rmse_m, 0.005);
}

}  // namespace
}  // namespace rekon::tracker
