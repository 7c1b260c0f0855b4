// Separate hosts: rekon-player and rekon-tracker on one host, rekon-optimiser
// and rekon-mapper on another (namespaces with their own hostnames, a veth
// pair between them, multicast routed over it, lcm ttl=1). transport auto must
// fall back to inline LCM because the mapper's heartbeat names another host,
// and the outputs must match the same four services on one host (shm).
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "rekon/common/mesh.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/eval/surface_eval.hpp"
#include "rekon/synth/synth.hpp"
#include "test_support.hpp"

namespace rekon {
namespace {

// Long enough for the tracker to start several keyframes, short enough for
// two runs under ThreadSanitizer.
constexpr int kFrames = 60;

using rekon::test::readText;

class Hosts : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    data_ = new test::TempDir;
    synth::SequenceOptions sequence;
    sequence.scene = "room";
    sequence.frames = kFrames;
    synth::writeSequence(sequence, *data_ / "room");
  }
  static void TearDownTestSuite() {
    delete data_;
    data_ = nullptr;
  }
  void SetUp() override {
    if (test::runCommand("unshare -n -u true") != 0) GTEST_SKIP() << "cannot create network/UTS namespaces (unshare -n -u)";
  }
  // Runs the four services in `mode` (one|two hosts) into data_/mode; returns the script's output.
  static std::string run(const std::string& mode, int* rc) {
    std::string out;
    *rc = test::runCommand(test::sourceDir() + "/tests/hosts/run_hosts.sh " + mode + " " + test::binDir() + " " +
                               (*data_ / "room") + " " + (*data_ / mode),
                           &out);
    return out;
  }
  static test::TempDir* data_;
};
test::TempDir* Hosts::data_ = nullptr;

TEST_F(Hosts, TwoHostsSendImagesInlineAndMatchTheSingleHostRun) {
  int rc = 0;
  const std::string one = run("one", &rc);
  ASSERT_EQ(rc, 0) << one;
  const std::string two = run("two", &rc);
  ASSERT_EQ(rc, 0) << two;
  const std::string dir_one = *data_ / "one", dir_two = *data_ / "two";

  // auto: every consumer on the player's host -> shm; the mapper elsewhere -> inline.
  EXPECT_NE(readText(dir_one + "/player.log").find("transport auto: shm"), std::string::npos);
  EXPECT_NE(readText(dir_two + "/player.log").find("transport auto: inline LCM"), std::string::npos);
  EXPECT_NE(readText(dir_two + "/player.log").find("transport lcm"), std::string::npos);

  // Inline images are the dataset's PNG bytes (lossless), so the tracker sees
  // the same pixels: every frame's optimised pose agrees to well under 1 mm
  // (only the order in which the optimiser hears messages may differ).
  const Trajectory t1 = readTumTrajectory(dir_one + "/trajectory.txt");
  const Trajectory t2 = readTumTrajectory(dir_two + "/trajectory.txt");
  ASSERT_EQ(t1.size(), static_cast<size_t>(kFrames));
  ASSERT_EQ(t2.size(), t1.size());
  double worst = 0, worst_angle = 0;
  for (size_t i = 0; i < t1.size(); ++i) {
    EXPECT_DOUBLE_EQ(t1[i].timestamp, t2[i].timestamp);
    worst = std::max(worst, translationDistance(t1[i].pose, t2[i].pose));
    worst_angle = std::max(worst_angle, rotationAngle(t1[i].pose, t2[i].pose));
  }
  EXPECT_LT(worst, 1e-3) << "largest per-frame difference between the two runs, m";
  EXPECT_LT(worst_angle, 1e-3) << "largest per-frame rotation difference, rad (0.06 degrees)";

  // The meshes: same size within 1 % and each surface within 1 mm of the other
  // on average (a frame lost or fused at a wrong pose moves it by centimetres).
  const Mesh m1 = readPly(dir_one + "/mesh.ply");
  const Mesh m2 = readPly(dir_two + "/mesh.ply");
  ASSERT_GT(m1.vertices.size(), 1000u);
  EXPECT_NEAR(static_cast<double>(m2.vertices.size()), static_cast<double>(m1.vertices.size()),
              0.01 * static_cast<double>(m1.vertices.size()));
  const eval::SurfaceErrors e = eval::evaluateSurface(m2, m1);
  EXPECT_LT(e.corr_m, 1e-3);
  EXPECT_LT(e.compl_m, 1e-3);
  std::cout << "two hosts vs one: " << t1.size() << " frames, largest pose difference " << worst * 1e3 << " mm, mesh "
            << m2.vertices.size() << " vs " << m1.vertices.size() << " vertices, corr " << e.corr_m * 1e3
            << " mm, compl " << e.compl_m * 1e3 << " mm\n";
}

}  // namespace
}  // namespace rekon
