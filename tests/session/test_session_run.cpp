// `rekon run --session` on the synthetic room, read back by `rekon remesh`
// and `rekon export`; runs killed mid-way (the mapper alone, or everything at
// once) leave sessions that open and continue; a second run never writes over a session.
#include <gtest/gtest.h>

#include <filesystem>
#include <regex>
#include <sstream>

#include "rekon/common/mesh.hpp"
#include "rekon/common/pose.hpp"
#include "test_support.hpp"

namespace {

namespace fs = std::filesystem;
using rekon::test::ateOf;
using rekon::test::binDir;
using rekon::test::readText;
using rekon::test::runCommand;
using rekon::test::valueAfter;

constexpr int kFrames = 150;

// CORR of `mesh` against `reference`; with `trajectories` ("--est-trajectory
// EST --gt-trajectory GT") the mesh is first moved into the reference's world.
double corr(const std::string& mesh, const std::string& reference, const std::string& trajectories = "") {
  std::string out;
  runCommand(binDir() + "/rekon eval surface " + mesh + " " + reference + " " + trajectories, &out);
  return valueAfter(out, "corr_m");
}

// The room's frames and one run with --session, shared by the tests.
class SessionRun : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new rekon::test::TempDir();
    ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene room --frames " + std::to_string(kFrames) +
                         " --out " + data()), 0);
    run_rc_ = runCommand(rekon::test::inNetns() + " timeout 240 " + binDir() + "/rekon run --dataset " + data() +
                             " --out " + run() + " --session " + session(),
                         &run_log_);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  void SetUp() override { ASSERT_EQ(run_rc_, 0) << run_log_; }
  static std::string data() { return *dir_ / "room"; }
  static std::string run() { return *dir_ / "run"; }
  static std::string session() { return *dir_ / "session"; }
  static rekon::test::TempDir* dir_;
  static int run_rc_;
  static std::string run_log_;
};
rekon::test::TempDir* SessionRun::dir_ = nullptr;
int SessionRun::run_rc_ = -1;
std::string SessionRun::run_log_;

// Re-meshing at the session's voxel size reproduces the run's mesh; at 5 mm
// the mesh is ~4.7x finer. It is not closer to the truth here: the room's
// Kinect-like noise (disparity steps of several mm at 1-3 m) is above 5 mm's
// averaging, and CORR measured 1.42 / 1.57 / 1.64 / 1.76 mm at 20 / 10 / 7.5 /
// 5 mm voxels. So the 5 mm mesh is bounded to 1.25x the 1 cm CORR (1.12x measured).
TEST_F(SessionRun, RemeshReproducesTheRunsMeshAndRebuildsItAtFinerVoxels) {
  std::string out1, out5;
  ASSERT_EQ(runCommand(binDir() + "/rekon remesh " + session() + " --out " + (*dir_ / "remesh_1cm.ply"), &out1), 0) << out1;
  ASSERT_EQ(runCommand(binDir() + "/rekon remesh " + session() + " --voxel 0.005 --out " + (*dir_ / "remesh_5mm.ply"), &out5), 0)
      << out5;
  // At the session's own settings: the run's keyframes at the run's final poses, the run's mesh.
  // 0.103 mm measured: the run's mesh went through de- and re-integrations, the re-mesh did not.
  const double same = corr(*dir_ / "remesh_1cm.ply", run() + "/mesh.ply");
  EXPECT_GE(same, 0.0);
  EXPECT_LT(same, 5e-4);
  const std::string into_gt = "--est-trajectory " + run() + "/trajectory.txt --gt-trajectory " + data() + "/groundtruth.txt";
  const double run_corr = corr(run() + "/mesh.ply", data() + "/mesh_gt.ply", into_gt);
  const double fine_corr = corr(*dir_ / "remesh_5mm.ply", data() + "/mesh_gt.ply", into_gt);
  EXPECT_GT(run_corr, 0.0);
  EXPECT_LT(fine_corr, 1.25 * run_corr);
  const auto triangles = [](const std::string& out) { return valueAfter(out, "triangles"); };
  EXPECT_GT(triangles(out5), 4 * triangles(out1));  // 2544789 vs 542095 measured
  const double run_s = rekon::test::jsonNumber(readText(run() + "/stats.json"), "wall_seconds");
  std::cout << "CORR 1 cm run " << run_corr << " m, 5 mm re-mesh " << fine_corr << " m; re-mesh at 1 cm vs mesh.ply " << same
            << " m; re-mesh 5 mm " << valueAfter(out5, "seconds") << " s vs run " << run_s << " s\n";
}

TEST_F(SessionRun, ExportWritesTheRunsTrajectoryItsGraphAndAMesh) {
  std::string out;
  ASSERT_EQ(runCommand(binDir() + "/rekon export " + session() + " --out " + (*dir_ / "export"), &out), 0) << out;
  // The fused frames at the final graph's poses: the optimiser's trajectory.txt.
  const double run_ate = ateOf(data() + "/groundtruth.txt", run() + "/trajectory.txt");
  const double export_ate = ateOf(data() + "/groundtruth.txt", *dir_ / "export/trajectory.txt");
  EXPECT_GT(run_ate, 0.0);
  EXPECT_NEAR(export_ate, run_ate, 1e-6);
  const std::string g2o = readText(*dir_ / "export/graph.g2o");
  const std::regex vertex("VERTEX_SE3:QUAT");
  const auto vertices = std::distance(std::sregex_iterator(g2o.begin(), g2o.end(), vertex), std::sregex_iterator());
  EXPECT_EQ(vertices, rekon::test::jsonInt(readText(run() + "/optimiser_stats.json"), "keyframes"));
  EXPECT_NE(g2o.find("EDGE_SE3:QUAT"), std::string::npos);
  EXPECT_GT(rekon::readPly(*dir_ / "export/mesh.ply").triangles.size(), 10000u);
  // Refused: writing into the session itself.
  EXPECT_NE(runCommand(binDir() + "/rekon export " + session() + " --out " + session(), &out), 0);
  EXPECT_NE(out.find("the session folder itself"), std::string::npos) << out;
}

TEST_F(SessionRun, ASecondRunNeverWritesOverTheSession) {
  const std::string anchors = readText(session() + "/anchors.txt"), yaml = readText(session() + "/session.yaml");
  std::string out;
  EXPECT_NE(runCommand(binDir() + "/rekon run --dataset " + data() + " --out " + (*dir_ / "again") + " --session " + session(), &out), 0);
  EXPECT_NE(out.find("already holds a session"), std::string::npos) << out;
  EXPECT_EQ(readText(session() + "/anchors.txt"), anchors);
  EXPECT_EQ(readText(session() + "/session.yaml"), yaml);
}

struct Killed {
  int rc = -1;      // rekon run's exit status (125: nothing was killed)
  std::string log;  // the kill script's output and rekon run's
};

// tests/faults/kill_during_run.sh: SERVICE killed with SIGKILL once the
// mapper's store holds 3 KF keyframes ("all": every process at once).
Killed runKilling(const std::string& service, const rekon::test::TempDir& dir) {
  EXPECT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene room --frames " + std::to_string(kFrames) +
                       " --out " + (dir / "room")), 0);
  Killed k;
  k.rc = runCommand(rekon::test::inNetns() + " " + rekon::test::sourceDir() + "/tests/faults/kill_during_run.sh " +
                        binDir() + " " + service + " 3 " + (dir / "run") + " --dataset " + (dir / "room") +
                        " --session " + (dir / "session"),
                    &k.log);
  k.log += "\nrekon run:\n" + readText(dir / "run/run.out");
  return k;
}

// A restartable service killed: rekon run restarted it once (its own line and
// its stats say so) and the run ended well.
void expectRestartedOnce(const Killed& k, const std::string& service, const rekon::test::TempDir& dir) {
  EXPECT_EQ(k.rc, 0) << k.log;
  EXPECT_NE(k.log.find("restarted rekon-" + service + " (pid"), std::string::npos) << k.log;
  const std::string stats = readText(dir / "run/stats.json");
  EXPECT_NE(stats.find("\"restarts\": {\"" + service + "\":1}"), std::string::npos) << stats;
}

// A run killed whole leaves its shared memory (frame ring, keyframe store):
// removed here.
void removeLeftovers(const rekon::test::TempDir& dir) {
  for (const std::string& segment : rekon::test::leftoverSegments(dir / "run"))
    runCommand(binDir() + "/rekon keyframes --remove --segment " + segment + "; rm -f /dev/shm/" + segment);
}

// A killed run's session continued with the frames after the last it kept
// (the last 30 again when it kept them all): the new run relocalises against
// it and maps the rest of the room into it.
void expectContinues(const rekon::test::TempDir& dir) {
  std::istringstream frames(readText(dir / "session/frames.txt"));
  long long last = -1;
  for (std::string line; std::getline(frames, line);) {
    std::istringstream l(line);
    if (long long id = 0; l >> id) last = std::max(last, id);
  }
  ASSERT_GE(last, 0);
  std::string out;
  ASSERT_EQ(runCommand(rekon::test::inNetns() + " timeout 240 " + binDir() + "/rekon run --dataset " + (dir / "room") +
                           " --out " + (dir / "continued") + " --continue " + (dir / "session") +
                           " --set player.first_frame=" + std::to_string(std::min<long long>(last + 1, kFrames - 30)),
                       &out), 0) << out;
  const std::string tracker = readText(dir / "continued/tracker_stats.json");
  EXPECT_GE(rekon::test::jsonInt(tracker, "relocalisations"), 1) << tracker;
  ASSERT_EQ(runCommand(binDir() + "/rekon export " + (dir / "session") + " --out " + (dir / "export_continued"), &out), 0) << out;
  const size_t poses = rekon::readTumTrajectory(dir / "export_continued/trajectory.txt").size();
  // Frames of both runs, less the lost ones: those the continued run lost
  // while it relocalised against the session. How many that takes depends on
  // the machine's load (a relocalisation has lost_relocalise_budget_ms of wall
  // time per frame: 12 frames in a CI run, where the bound used to count them).
  const long long lost = rekon::test::jsonInt(tracker, "lost_frames");
  EXPECT_GE(static_cast<long long>(poses) + lost, kFrames - 10) << "frames of both runs, less the lost ones\n" << tracker;
}

// Everything killed at once: the session holds the keyframes written before
// (at least the 3 the store held, less any in flight), re-meshes and continues.
TEST(SessionKilled, ARunKilledWholeLeavesASessionThatOpensAndRemeshes) {
  rekon::test::TempDir dir;
  const Killed k = runKilling("all", dir);
  ASSERT_NE(k.log.find("killed all"), std::string::npos) << k.log;
  std::string out;
  ASSERT_EQ(runCommand(binDir() + "/rekon remesh " + (dir / "session") + " --out " + (dir / "remesh.ply"), &out), 0) << out;
  EXPECT_GE(valueAfter(out, "keyframes"), 2) << out;
  EXPECT_GT(rekon::readPly(dir / "remesh.ply").triangles.size(), 1000u);
  EXPECT_EQ(runCommand(binDir() + "/rekon export " + (dir / "session") + " --out " + (dir / "export"), &out), 0) << out;
  removeLeftovers(dir);
  expectContinues(dir);
}

// The mapper killed and restarted by rekon run goes on writing the same
// session, which then re-meshes into the run's mesh and continues.
TEST(SessionKilled, AMapperRestartedMidRunGoesOnWritingTheSameSession) {
  rekon::test::TempDir dir;
  const Killed k = runKilling("mapper", dir);
  ASSERT_NE(k.log.find("killed rekon-mapper"), std::string::npos) << k.log;
  expectRestartedOnce(k, "mapper", dir);
  std::string out;
  ASSERT_EQ(runCommand(binDir() + "/rekon remesh " + (dir / "session") + " --out " + (dir / "remesh.ply"), &out), 0) << out;
  const double same = corr(dir / "remesh.ply", dir / "run/mesh.ply");
  EXPECT_GE(same, 0.0);
  EXPECT_LT(same, 5e-4) << out;  // as an uninterrupted run's: 0.103 mm measured
  expectContinues(dir);
}

// The tracker killed (restarted, it rebuilds from its journal and keyframe
// archive) or the optimiser killed (restarted, it rebuilds from its journal
// and the tracker's replay): either session opens and continues.
TEST(SessionKilled, RunsWithTheTrackerOrTheOptimiserKilledLeaveSessionsThatContinue) {
  for (const std::string service : {"tracker", "optimiser"}) {
    SCOPED_TRACE(service);
    rekon::test::TempDir dir;
    const Killed k = runKilling(service, dir);
    ASSERT_NE(k.log.find("killed rekon-" + service), std::string::npos) << k.log;
    expectRestartedOnce(k, service, dir);
    removeLeftovers(dir);
    expectContinues(dir);
  }
}

}  // namespace
