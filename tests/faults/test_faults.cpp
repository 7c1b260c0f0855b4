// Faults a run must survive (issue 9): services killed with SIGKILL mid-run
// and messages lost on the bus. Each faulty run of a small synthetic room is
// compared with an uninterrupted run of the same build on the same data.
// Every process runs under a timeout in a private network namespace.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "test_support.hpp"

namespace fs = std::filesystem;
using rekon::test::runCommand;

namespace {

// 3 s of the synthetic room: 4 KF keyframes at kappa 20, small enough for a
// loaded 2-core machine, long enough to kill a service with 2 of them stored.
// The uninterrupted run, twice (two builds): ATE 0.226506 mm, CORR 1.668413 mm
// both times. Each bound below is from the differences to it measured in
// runs of this test on a loaded 2-core machine, with the margin said there.
constexpr int kFrames = 90;
constexpr int kKillAfterKeyframes = 2;

std::string bin() { return rekon::test::binDir(); }
using rekon::test::inNetns;

using rekon::test::readText;

// The room and an uninterrupted run of it, made once per build of the
// services (cached beside the binaries; a lock lets parallel tests share it).
struct Baseline {
  std::string data, run;
};
const Baseline& baseline() {
  static const Baseline b = [] {
    std::string key = std::to_string(kFrames) + "_";
    for (const char* s : {"rekon", "rekon-player", "rekon-tracker", "rekon-optimiser", "rekon-mapper"}) {
      struct stat st {};
      stat((bin() + "/" + s).c_str(), &st);
      key += std::to_string(st.st_mtime % 100000) + "_";
    }
    const std::string dir = bin() + "/../test_faults_cache/" + key;
    Baseline r{dir + "/room", dir + "/run"};
    std::string out;
    const int rc = runCommand("mkdir -p " + dir + " && flock " + dir + "/lock bash -c '[ -f " + r.run + "/stats.json ] || { " +
                                  "timeout 120 " + bin() + "/rekon synth --scene room --frames " + std::to_string(kFrames) +
                                  " --out " + r.data + " && " + inNetns() + " timeout 240 " + bin() + "/rekon run --dataset " +
                                  r.data + " --out " + r.run + "; }'",
                              &out);
    EXPECT_EQ(rc, 0) << out;
    return r;
  }();
  return b;
}

using rekon::test::valueAfter;

// CORR (m) of a run's mesh against the room's exact surface, the mesh moved
// into the ground truth's world by the ATE alignment.
double corrOf(const std::string& run) {
  const Baseline& b = baseline();
  std::string out;
  runCommand(bin() + "/rekon eval surface " + run + "/mesh.ply " + b.data + "/mesh_gt.ply --est-trajectory " + run +
                 "/trajectory.txt --gt-trajectory " + b.data + "/groundtruth.txt",
             &out);
  const double corr = valueAfter(out, "corr_m");
  EXPECT_GE(corr, 0.0) << out;
  std::printf("CORR %s: %.6f mm\n", run.c_str(), 1e3 * corr);
  return corr;
}

// ATE RMSE (m) of a run's trajectory against the ground truth.
double ateOf(const std::string& run) {
  std::string out;
  runCommand(bin() + "/rekon eval traj " + baseline().data + "/groundtruth.txt " + run + "/trajectory.txt", &out);
  const double ate = valueAfter(out, "ate_rmse_m");
  EXPECT_GE(ate, 0.0) << out;
  std::printf("ATE %s: %.6f mm\n", run.c_str(), 1e3 * ate);
  return ate;
}

size_t lineCount(const std::string& path) {
  std::ifstream in(path);
  size_t n = 0;
  for (std::string l; std::getline(in, l);)
    if (!l.empty() && l[0] != '#') ++n;
  return n;
}

using rekon::test::leftoverSegments;

struct Faulty {
  int rc = -1;  // rekon run's exit status (125: the kill script killed nothing)
  std::string output;  // the kill script's and rekon run's
};

// `rekon run` on the room with `service` killed once `after_keyframes` KF keyframes are stored.
Faulty runKilling(const std::string& service, const std::string& out, const std::string& sets = "",
                  int after_keyframes = kKillAfterKeyframes, const std::string& env = "") {
  Faulty f;
  f.rc = runCommand(env + " " + inNetns() + " " + rekon::test::sourceDir() + "/tests/faults/kill_during_run.sh " + bin() + " " + service +
                        " " + std::to_string(after_keyframes) + " " + out + " --dataset " + baseline().data + " " + sets,
                    &f.output);
  f.output += "\nrekon run:\n" + readText(out + "/run.out") + "\nkill checks:\n" + readText(out + "/kill_checks.log");
  return f;
}

TEST(Faults, KilledMapperIsRestartedAndItsMeshMatchesAnUninterruptedRun) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling("mapper", out);
  ASSERT_NE(f.output.find("killed rekon-mapper"), std::string::npos) << f.output;
  ASSERT_EQ(f.rc, 0) << f.output;
  EXPECT_NE(readText(out + "/stats.json").find("\"restarts\": {\"mapper\":1}"), std::string::npos) << f.output;
  // The restarted mapper rebuilt from its store and got every later frame again.
  EXPECT_NE(readText(out + "/player.log").find("rekon-mapper restarted: sending frames"), std::string::npos)
      << readText(out + "/player.log");
  // CORR as the uninterrupted run's: measured the same to 1 nm in 4 runs (no loop closure: the
  // restarted mapper integrates the same keyframes at the same poses). 0.02 mm (1 % of CORR) leaves
  // room for another machine's timing; a keyframe lost or fused twice moves CORR by more.
  EXPECT_NEAR(corrOf(out), corrOf(baseline().run), 0.00002) << readText(out + "/mapper.log");
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// Killed once it stored the last KF keyframe (5 of the room's 90 frames),
// which it does in its final pass, moments before it exits: the kill script
// holds it stopped while it counts, so the kill lands. Where it lands decides
// what the restart does, and both must end the run with the same map. The
// map goes on the bus unasked here: sending every block at the end keeps the
// mapper alive ~0.5 s after that store, longer than the script lets it run
// between two checks (0.1 s); without it the mapper can finish between them
// and nothing is killed (the CI rehearsal of 2026-12-03, evidence
// /tmp/rekon_test_Hp2SFK):
// - before the store is marked finished: the restart rebuilds from the store;
//   its resume point is past the last frame, so nothing is sent again, but
//   the player announces the end of the stream again (it once waited for ever);
// - after (its outputs written, its done_t perhaps sent): the restart says the
//   end again and exits (it once waited 120 s for an end of stream nobody
//   sends again; the CI rehearsal of 2026-12-03 caught that, evidence
//   /tmp/rekon_test_4EysXZ). test_mapper_service covers this case on its own.
TEST(Faults, MapperKilledAfterTheLastFrameGetsTheEndOfTheStreamAgain) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling("mapper", out, "--set mapper.mesh_publish_unasked=true", 5);
  ASSERT_NE(f.output.find("killed rekon-mapper"), std::string::npos) << f.output;
  ASSERT_NE(f.output.find("with 5 KF keyframes stored"), std::string::npos) << f.output;
  const std::string logs = f.output + "\nplayer.log:\n" + readText(out + "/player.log") + "mapper.log:\n" + readText(out + "/mapper.log");
  ASSERT_EQ(f.rc, 0) << logs;
  EXPECT_NE(readText(out + "/stats.json").find("\"restarts\": {\"mapper\":1}"), std::string::npos) << f.output;
  const bool rebuilt = readText(out + "/player.log").find("sending frames 90..89 again") != std::string::npos;
  const bool said_again = readText(out + "/mapper.log").find("its run finished at frame 89") != std::string::npos;
  std::printf("the restart %s\n", rebuilt ? "rebuilt from the store" : said_again ? "found the run finished" : "did neither");
  EXPECT_TRUE(rebuilt || said_again) << logs;
  EXPECT_NEAR(corrOf(out), corrOf(baseline().run), 0.00002) << readText(out + "/mapper.log");
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// The same behind a live source (player.pacing live), killed once it heard
// the end of the stream: a live source sends no frame again, but it announces
// the end again to the restart. It once did not: the restarted mapper waited
// for an end of stream until the player happened to be restarted too (the
// corridor chaos run, 4 minutes), or for ever.
TEST(Faults, MapperKilledAfterTheEndOfALiveStreamHearsTheEndAgain) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling("mapper", out, "--set player.rate=1 --set player.pacing=live", 1, "KILL_COUNT=ended");
  ASSERT_NE(f.output.find("killed rekon-mapper"), std::string::npos) << f.output;
  const std::string logs = f.output + "\nplayer.log:\n" + readText(out + "/player.log") + "mapper.log:\n" + readText(out + "/mapper.log");
  ASSERT_EQ(f.rc, 0) << logs;
  EXPECT_NE(readText(out + "/stats.json").find("\"restarts\": {\"mapper\":1}"), std::string::npos) << f.output;
  const bool rebuilt = readText(out + "/mapper.log").find("the volume is rebuilt from them") != std::string::npos;
  const bool said_again = readText(out + "/mapper.log").find("its run finished at frame") != std::string::npos;
  std::printf("the restart %s\n", rebuilt ? "rebuilt from the store" : said_again ? "found the run finished" : "did neither");
  EXPECT_TRUE(rebuilt || said_again) << logs;
  const bool announced = readText(out + "/player.log").find("announcing the end again") != std::string::npos;
  EXPECT_TRUE(announced || !rebuilt) << logs;
  EXPECT_NE(readText(out + "/trajectory.txt"), "") << logs;
  EXPECT_TRUE(fs::exists(out + "/mesh.ply")) << logs;
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// The mapper held stopped in its final pass until every other service has
// exited (they take its silence for its end), then killed: the last service
// standing. The launcher waits for its restart, which rebuilds from the store
// and writes the outputs. The run once ended at the kill with exit 0 and no
// mesh.ply while the restart was still working (tools/rekon stress, 1 of 20
// runs of the test above beside two CPU hogs, a check that held the mapper
// stopped for seconds; always, with KILL_ALONE).
TEST(Faults, TheLastServiceStandingKilledIsRestartedAndTheRunWaitsForItsOutputs) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling("mapper", out, "--set lifecycle.silence_s=2 --set lifecycle.silence_gaps=2", 5,
                              "KILL_ALONE=1");
  ASSERT_NE(f.output.find("killed rekon-mapper"), std::string::npos) << f.output;
  ASSERT_NE(f.output.find("every other service has exited"), std::string::npos) << f.output;
  const std::string logs = f.output + "\nmapper.log:\n" + readText(out + "/mapper.log");
  ASSERT_EQ(f.rc, 0) << logs;
  EXPECT_NE(readText(out + "/stats.json").find("\"restarts\": {\"mapper\":1}"), std::string::npos) << f.output;
  EXPECT_NEAR(corrOf(out), corrOf(baseline().run), 0.00002) << logs;
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// The mapper killed after fusing 5 frames, before its first KF keyframe (20
// frames) was stored: the restart finds its store empty and resumes at frame
// 0, so the player sends every frame again. It once announced no resume
// point and lost the frames its killed instance was fusing (a chaos run,
// tools/rekon stress 1 of 20: 26 frames dropped, the mesh 2.9 mm off).
// At a quarter of the recorded rate, 7.5 frames/s: the window of frames 5-19
// is 2 s wide. At full speed the stream ran past frame 20 between two kill
// checks in 5 of 8 runs beside two CPU hogs, at the recorded rate in 3 of 20
// (checks 0.6-0.9 s apart under that load: 3 fused, then 27).
TEST(Faults, AMapperKilledBeforeItsFirstKeyframeWasStoredGetsEveryFrameAgain) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling("mapper", out, "--set player.rate=0.25", 5, "KILL_COUNT=fused");
  ASSERT_NE(f.output.find("killed rekon-mapper"), std::string::npos) << f.output;
  const std::string logs = f.output + "\nplayer.log:\n" + readText(out + "/player.log") + "mapper.log:\n" +
                           readText(out + "/mapper.log");
  ASSERT_EQ(f.rc, 0) << logs;
  EXPECT_NE(readText(out + "/mapper.log").find("resuming at frame 0"), std::string::npos) << logs;
  EXPECT_NE(readText(out + "/mapper_stats.json").find("\"frames_fused\": 90"), std::string::npos) << logs;
  EXPECT_NEAR(corrOf(out), corrOf(baseline().run), 0.00002) << logs;
}

// The optimiser killed, restarted, rebuilt from its journal and the tracker's replay: with
// the player at full speed the tracker is done by then (the mapper's store,
// which times the kill, lags it); at the recorded rate it is mid-stream.
void expectOptimiserRebuilt(const std::string& sets) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling("optimiser", out, sets);
  ASSERT_NE(f.output.find("killed rekon-optimiser"), std::string::npos) << f.output;
  ASSERT_EQ(f.rc, 0) << f.output;
  EXPECT_NE(readText(out + "/stats.json").find("\"restarts\": {\"optimiser\":1}"), std::string::npos);
  const std::string optimiser_log = readText(out + "/optimiser.log");
  const std::string logs = "optimiser.log:\n" + optimiser_log + "tracker.log:\n" + readText(out + "/tracker.log");
  // What the killed instance had heard comes from its journal, the rest from the tracker;
  // its updates are numbered after the killed instance's.
  EXPECT_NE(optimiser_log.find("rebuilt from optimiser_journal.rkj"), std::string::npos) << logs;
  EXPECT_NE(optimiser_log.find("graph updates continue after version"), std::string::npos) << logs;
  EXPECT_EQ(lineCount(out + "/trajectory.txt"), static_cast<size_t>(kFrames)) << logs;
  // ATE as the uninterrupted run's: measured the same to 1 nm in 5 runs of each of the two tests
  // (the rebuilt graph has the same edges). 0.002 mm (1 % of ATE) leaves room for another
  // machine's timing; a missing or doubled edge moves it by more.
  EXPECT_NEAR(ateOf(out), ateOf(baseline().run), 0.000002);
  // optimiser_timing.csv grows as the run goes: the killed instance's rows
  // stay and the restart's follow them (one header, more rows than the
  // restart's own optimisations).
  const std::string timing = readText(out + "/optimiser_timing.csv");
  const std::string stats = readText(out + "/optimiser_stats.json");
  EXPECT_EQ(timing.find("frame_id,ms,keyframes,graph_version"), 0u) << timing;
  EXPECT_EQ(timing.find("frame_id", 1), std::string::npos) << timing;
  EXPECT_GT(lineCount(out + "/optimiser_timing.csv") - 1, static_cast<size_t>(rekon::test::jsonInt(stats, "optimisations")))
      << timing << stats;
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

TEST(Faults, KilledOptimiserRebuildsItsGraphFromTheTrackerAndTheTrajectoryMatches) { expectOptimiserRebuilt(""); }

// At the recorded rate (player.pacing: wait, the default) the player waits for acknowledgements
// too, so a tracker behind the clock loses no frame from the ring's 8 slots.
TEST(Faults, OptimiserKilledMidStreamRebuildsAndTheTrajectoryMatches) { expectOptimiserRebuilt("--set player.rate=1"); }

// Issue 25, finding 1: the optimiser killed after its done_t, while it
// lingers for the mapper (held stopped by the script until the kill, so the
// moment is certain). The killed instance's done_t must not stand for its
// restart's: the tracker keeps serving until the restart is done and has
// exited, the restart rebuilds from the whole replay and goes to its final
// step, and the run ends on its own (it hung for 120 s). Silence 30 s: the
// mapper's stop is not taken for its exit.
TEST(Faults, OptimiserKilledAfterItsDoneIsRestartedAndTheRunFinishes) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  std::string output;
  const int rc = runCommand(inNetns() + " " + rekon::test::sourceDir() + "/tests/faults/kill_optimiser_after_done.sh " +
                                bin() + " " + out + " --dataset " + baseline().data + " --set lifecycle.silence_s=30",
                            &output);
  output += "\nrekon run:\n" + readText(out + "/run.out");
  ASSERT_NE(output.find("killed rekon-optimiser"), std::string::npos) << output;
  ASSERT_EQ(rc, 0) << output;
  EXPECT_NE(readText(out + "/stats.json").find("\"restarts\": {\"optimiser\":1}"), std::string::npos) << output;
  const std::string optimiser_log = readText(out + "/optimiser.log");
  const std::string logs = "optimiser.log:\n" + optimiser_log + "tracker.log:\n" + readText(out + "/tracker.log");
  EXPECT_NE(optimiser_log.find("rebuilt from optimiser_journal.rkj"), std::string::npos) << logs;
  EXPECT_NE(optimiser_log.find("graph updates continue after version"), std::string::npos) << logs;
  EXPECT_NE(optimiser_log.find("the tracker finished before this optimiser started"), std::string::npos) << logs;
  EXPECT_EQ(lineCount(out + "/trajectory.txt"), static_cast<size_t>(kFrames)) << logs;
  EXPECT_NEAR(ateOf(out), ateOf(baseline().run), 0.000002);  // the bound of expectOptimiserRebuilt
  EXPECT_TRUE(fs::exists(out + "/mesh.ply") && fs::file_size(out + "/mesh.ply") > 1000) << output;
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// A dead service that run.restart does not list (or that cannot recover)
// stops the run: it says which service died, exits non-zero, and keeps what
// was made so far.
void expectStoppedNaming(const std::string& service, const std::string& sets = "") {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling(service, out, sets);
  ASSERT_NE(f.output.find("killed rekon-" + service), std::string::npos) << f.output;
  EXPECT_NE(f.rc, 0) << f.output;
  EXPECT_NE(f.output.find("rekon-" + service + " was killed by signal 9"), std::string::npos) << f.output;
  // The trajectory up to the last frame tracked (2 KF keyframes = 40 frames at least), and the mesh.
  const size_t frames = lineCount(out + "/trajectory.txt");
  EXPECT_GE(frames, 40u);
  EXPECT_LE(frames, static_cast<size_t>(kFrames));
  EXPECT_TRUE(fs::exists(out + "/mesh.ply") && fs::file_size(out + "/mesh.ply") > 1000) << f.output;
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

TEST(Faults, KilledPlayerNotListedInRunRestartStopsTheRunNamingIt) {
  expectStoppedNaming("player", "--set run.restart=[mapper,optimiser]");
}

// `service` killed mid-stream (2 KF keyframes stored) and restarted by rekon
// run: every frame tracked once, ATE and the mesh's CORR against the room's
// ground truth within `ate_bound_m` and `corr_bound_m` of the uninterrupted run's.
void expectRestartedWithinBounds(const std::string& service, const std::string& log_line, double ate_bound_m,
                                 double corr_bound_m) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling(service, out);
  ASSERT_NE(f.output.find("killed rekon-" + service), std::string::npos) << f.output;
  ASSERT_EQ(f.rc, 0) << f.output;
  EXPECT_NE(readText(out + "/stats.json").find("\"restarts\": {\"" + service + "\":1}"), std::string::npos) << f.output;
  const std::string log = readText(out + "/" + service + ".log");
  EXPECT_NE(log.find(log_line), std::string::npos) << log;
  EXPECT_EQ(lineCount(out + "/trajectory.txt"), static_cast<size_t>(kFrames)) << f.output;
  EXPECT_NEAR(ateOf(out), ateOf(baseline().run), ate_bound_m);
  EXPECT_NEAR(corrOf(out), corrOf(baseline().run), corr_bound_m);
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// The player: the new instance asks its consumers' heartbeats where they are
// and goes on after that; the same frames are tracked and fused in the same
// order. Measured: ATE and CORR equal to the uninterrupted run's to 1 nm
// (0.2265 and 1.6685 mm). Bounds 0.01 mm.
TEST(Faults, KilledPlayerIsRestartedAndGoesOnWhereItsConsumersAre) {
  expectRestartedWithinBounds("player", "restarted: the consumers have the frames up to", 0.00001, 0.00001);
}

// The player killed after its last frame (5 KF keyframes stored: the
// mapper's final pass): its consumers may finish and exit before its restart
// starts. Before, the restart waited 60 s for a mapper that had exited and
// failed the run (tools/rekon stress: 2 of 10 runs, whenever the kill
// landed that late); now one not heard within lifecycle.silence_s has
// finished, and the run ends well.
TEST(Faults, PlayerKilledAfterTheLastFrameIsRestartedAndTheRunFinishes) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling("player", out, "", 5);
  ASSERT_NE(f.output.find("killed rekon-player"), std::string::npos) << f.output;
  ASSERT_EQ(f.rc, 0) << f.output << readText(out + "/player.log");
  EXPECT_NE(readText(out + "/stats.json").find("\"restarts\": {\"player\":1}"), std::string::npos) << f.output;
  EXPECT_EQ(lineCount(out + "/trajectory.txt"), static_cast<size_t>(kFrames)) << f.output;
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// The tracker: rebuilt from its journal and keyframe archive, its first frame
// relocalised (or a new keyframe), the frames from its resume point sent
// again. Measured in 4 runs (resume at frames 42-83): ATE -0.009..+0.072 mm
// and CORR -0.25..+0.36 mm against the uninterrupted run (a different
// keyframe after the restart moves the map a little). Bounds: twice the
// largest difference, 0.15 and 0.7 mm.
TEST(Faults, KilledTrackerIsRestartedFromItsJournalAndGoesOn) {
  expectRestartedWithinBounds("tracker", "restarted: the journal holds", 0.00015, 0.0007);
}

TEST(Faults, MapperKilledMoreOftenThanMaxRestartsStopsTheRun) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  const Faulty f = runKilling("mapper", out, "--set run.max_restarts=0");
  ASSERT_NE(f.output.find("killed rekon-mapper"), std::string::npos) << f.output;
  EXPECT_NE(f.rc, 0) << f.output;
  EXPECT_NE(f.output.find("rekon-mapper was killed by signal 9"), std::string::npos) << f.output;
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// lcm.drop_fraction drops received messages in every service: frames, acknowledgements,
// keyframes, constraints, graph updates, done messages alike. Lost frames are neither
// tracked nor fused, so the result differs from the uninterrupted run's. Which messages are
// lost depends only on their channel and place on it (Bus::dropReceived), so a loss is the
// same in every run; it was a random stream shared with heartbeats and stats, which made the
// 5 % run's CORR vary by more than its bound (issue 48: +2.099 mm against a +0.4 mm bound).
// A lost first frame starts the whole run one frame later, from another reference:
// measured with player.first_frame=1, 2, 3 (no loss), ATE 0.129, 0.124, 0.121 mm and CORR
// 1.139, 1.140, 1.311 mm against the uninterrupted run's 0.227 and 1.668 mm. Such a run is
// better, not wrong, so ATE and CORR are bounded from above only.
void expectCompletesUnderLoss(double fraction, double ate_bound_m, double corr_bound_m) {
  rekon::test::TempDir dir;
  const std::string out = dir / "run";
  std::string output;
  const int rc = runCommand(inNetns() + " timeout 240 " + bin() + "/rekon run --dataset " + baseline().data + " --out " + out +
                                " --set lcm.drop_fraction=" + std::to_string(fraction),
                            &output);
  ASSERT_EQ(rc, 0) << output;
  // A frame lost on its way to the tracker is not tracked; the rest are.
  EXPECT_GE(lineCount(out + "/trajectory.txt"), static_cast<size_t>(kFrames * (1.0 - 3 * fraction)));
  std::printf("%.0f %% loss: ATE %+.4f mm, CORR %+.4f mm against the uninterrupted run\n", 100 * fraction,
              1e3 * (ateOf(out) - ateOf(baseline().run)), 1e3 * (corrOf(out) - corrOf(baseline().run)));
  EXPECT_LE(ateOf(out), ateOf(baseline().run) + ate_bound_m);
  EXPECT_LE(corrOf(out), corrOf(baseline().run) + corr_bound_m);
  EXPECT_EQ(leftoverSegments(out), std::vector<std::string>{});
}

// Measured in 5 runs, each the same: ATE and CORR +0.0000 mm against the uninterrupted run
// (the messages lost change nothing the final pass does not restore). Bounds: 0.05 mm each,
// for a change elsewhere that moves the result a little.
TEST(Faults, OnePercentMessageLossCompletesWithTheSameResult) { expectCompletesUnderLoss(0.01, 0.00005, 0.00005); }

// Measured in 5 runs, each the same: ATE -0.0975 mm, CORR -0.4328 mm (its losses include a
// frame early on: a better start, as above). Bounds as before: 0.05 mm and 0.4 mm above the
// uninterrupted run.
TEST(Faults, FivePercentMessageLossCompletesWithTheSameResult) { expectCompletesUnderLoss(0.05, 0.00005, 0.0004); }

// `rekon chaos` on the room against its cached uninterrupted run, given at
// most `timeout_s`; the caller appends the rest of the options.
std::string roomChaos(int timeout_s) {
  return inNetns() + " timeout " + std::to_string(timeout_s) + " " + bin() + "/rekon chaos --dataset " + baseline().data +
         " --baseline " + baseline().run;
}

// rekon chaos at small scale: the room at its recorded rate (3 s), a random
// restartable service killed every 0.7-1.5 s, compared with the cached
// uninterrupted run. Measured (seed 1, 2-core VM): 5 kills (player 4, mapper
// 1), 90 of 90 poses, ATE 0.23 mm as uninterrupted, the mesh 0.045 mm from
// the uninterrupted one: within rekon chaos's default bounds (95 % of the
// poses, ATE 1.5x + 0.5 mm, CORR 2 mm). With a bound no run can meet (more
// poses than frames), it says so and exits 1.
TEST(Faults, ChaosKillsRandomServicesAndTheRunStaysWithinItsBounds) {
  rekon::test::TempDir dir;
  const std::string chaos = roomChaos(240) + " --every 0.7-1.5 --seed 1 --out ";
  std::string output;
  ASSERT_EQ(runCommand(chaos + (dir / "held"), &output), 0) << output;
  const std::string json = readText(dir / "held/chaos.json");
  EXPECT_NE(json.find("\"within_bounds\": true"), std::string::npos) << json;
  EXPECT_GE(rekon::test::jsonInt(json, "kills"), 2) << output;
  EXPECT_NE(output.find("within bounds"), std::string::npos) << output;

  EXPECT_EQ(runCommand(chaos + (dir / "strict") + " --min-poses 1.01", &output), 1) << output;
  EXPECT_NE(output.find("out of bounds: 90 poses, fewer than 91"), std::string::npos) << output;
  EXPECT_EQ(leftoverSegments(dir / "held/chaos"), std::vector<std::string>{});
}

// A killed live player costs the frames due during its outage, and nothing
// else: rekon chaos --same-frames plays, uninterrupted, only the frames the
// killed run has poses for, and the two runs must agree. Measured (seed 1,
// 2-core VM, live pacing; once idle, 20 of 20 and 6 more beside two CPU
// hogs): 6 player kills, 67-72 of 90 poses, the trajectories at most 1.2e-16 m
// apart (RMSE) and the meshes 0.044-0.063 mm (CORR: the mapper's rounds
// follow graph updates as they come). Bounds: 1 um for the trajectory (a
// restart that cost anything beyond its frames moves it by 0.1 mm and more,
// the corridor's optimiser kills by 0.17 mm) and 0.2 mm for the mesh (3x the
// largest). The bounds against the uninterrupted run are loosened: a quarter
// of the room's frames lost moves its mesh 4 mm.
TEST(Faults, AKilledLivePlayerCostsOnlyTheFramesOfItsOutages) {
  rekon::test::TempDir dir;
  std::string output;
  ASSERT_EQ(runCommand(roomChaos(240) + " --services player --every 0.7-1.5 --seed 1 --set player.pacing=live" +
                           " --same-frames --min-poses 0.5 --max-corr-mm 20 --out " + (dir / "out"),
                       &output),
            0)
      << output;
  const std::string json = readText(dir / "out/chaos.json");
  EXPECT_GE(rekon::test::jsonInt(json, "kills"), 2) << output;
  EXPECT_LT(rekon::test::jsonInt(json, "poses"), kFrames) << "no frame was lost: the test shows nothing\n" << output;
  EXPECT_EQ(rekon::test::jsonInt(json, "same_frames_poses"), rekon::test::jsonInt(json, "poses")) << output;
  EXPECT_LE(rekon::test::jsonNumber(json, "trajectory_rmse_vs_same_frames_m"), 1e-6) << output;
  EXPECT_LE(rekon::test::jsonNumber(json, "corr_vs_same_frames_m"), 0.0002) << output;
  EXPECT_EQ(leftoverSegments(dir / "out/chaos"), std::vector<std::string>{});
  EXPECT_EQ(leftoverSegments(dir / "out/same_frames"), std::vector<std::string>{});
}

// A killed run that left no trajectory (here its player refuses a frame
// range beyond the dataset) leaves nothing to play again: one line says so,
// and the table and chaos.json still come, with the verdict.
TEST(Faults, ChaosSameFramesWithoutAKilledTrajectorySaysSoAndKeepsItsTable) {
  rekon::test::TempDir dir;
  std::string output;
  EXPECT_EQ(runCommand(roomChaos(120) + " --services player --set player.first_frame=1000 --same-frames --out " +
                           (dir / "out"),
                       &output),
            1)
      << output;
  EXPECT_NE(output.find("no run of the same frames: " + (dir / "out/chaos/trajectory.txt")), std::string::npos) << output;
  EXPECT_NE(output.find("out of bounds: no run of the same frames"), std::string::npos) << output;
  EXPECT_NE(output.find("n/a (no trajectory)"), std::string::npos) << output;
  EXPECT_NE(readText(dir / "out/chaos.json").find("\"same_frames_exit_status\": -1"), std::string::npos) << output;
}

TEST(Faults, RestartPolicyNamingAServiceThatCannotRecoverIsAnError) {
  rekon::test::TempDir dir;
  std::string out;
  const int rc = runCommand(bin() + "/rekon run --dataset " + dir.path() + " --out " + (dir / "out") +
                                " --set run.restart=[mapper,viewer]",
                            &out);
  EXPECT_EQ(rc, 1);
  EXPECT_NE(out.find("run.restart lists 'viewer', which cannot be restarted"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(dir / "out")) << "a refused run leaves no folder";
}

}  // namespace
