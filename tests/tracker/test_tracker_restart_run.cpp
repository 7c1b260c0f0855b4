// A restartable tracker (issue 48, item 1) as processes: rekon-player,
// rekon-tracker and rekon-optimiser started by hand on the synthetic room (as
// rekon run would, without its restart policy), the tracker killed with
// SIGKILL mid-run and started again with tracker.restarted=true on the same
// --out. The run goes on to the end and its trajectory matches an
// uninterrupted run's.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>

#include <chrono>
#include <fstream>
#include <set>
#include <thread>

#include "rekon/common/record_journal.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"
#include "test_support.hpp"

namespace {

using rekon::test::readText;
using rekon::test::runCommand;

// 3 s of the synthetic room (as tests/faults); the tracker is killed once
// its journal holds this many tracked frames, mid-stream.
constexpr int kFrames = 90;
constexpr int kKillAfterFrames = 45;
constexpr double kWaitS = 120.0;  // any process still running after this has hung

std::string bin() { return rekon::test::binDir(); }

// The room, written once per build of rekon (cached beside the binaries; a lock lets parallel tests share it).
std::string room() {
  static const std::string dir = [] {
    struct stat st {};
    stat((bin() + "/rekon").c_str(), &st);
    const std::string d = bin() + "/../test_tracker_restart_cache/" + std::to_string(kFrames) + "_" +
                          std::to_string(st.st_mtime % 100000);
    std::string out;
    const int rc = runCommand("mkdir -p " + d + " && flock " + d + "/lock bash -c '[ -f " + d +
                                  "/room/groundtruth.txt ] || timeout 120 " + bin() + "/rekon synth --scene room --frames " +
                                  std::to_string(kFrames) + " --out " + d + "/room'",
                              &out);
    EXPECT_EQ(rc, 0) << out;
    return d + "/room";
  }();
  return dir;
}

std::string settings(const std::string& out) {
  return rekon::test::ownSegments("trk_restart") + " --set 'player.wait_for=[tracker]' --out " + out;
}

pid_t spawnService(const std::string& name, const std::string& out, const std::string& extra, const std::string& log) {
  return rekon::test::spawnShell("exec " + bin() + "/rekon-" + name + " " + settings(out) + " " + extra + " > " + out +
                                 "/" + log + " 2>&1");
}

// Frame ids of the tracked frames the tracker's journal holds, each once.
std::set<int64_t> journaledFrames(const std::string& out) {
  std::set<int64_t> ids;
  for (const rekon::JournalRecord& r : rekon::readRecordJournal(out + "/tracker_state/journal.rkj").records) {
    if (r.tag != rekon::kTrackedFrameRecord) continue;
    if (const auto tf = rekon::decodeRecord<rekon_msgs::tracked_frame_t>(r)) ids.insert(tf->frame_id);
  }
  return ids;
}

// Every thread of `pid` stopped by SIGSTOP (alive and still), within 2 s.
bool stopped(pid_t pid) {
  const std::string all_stopped = "test \"$(sed 's/.*) //' /proc/" + std::to_string(pid) +
                                  "/task/*/stat 2>/dev/null | cut -d' ' -f1 | sort -u)\" = T";
  for (int i = 0; i < 100; ++i) {
    if (runCommand(all_stopped) == 0) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return false;
}

struct PipelineRun {
  std::string out;
  int player = -1, tracker = -1, restarted = -1, optimiser = -1;  // exit statuses
  size_t frames_at_kill = 0;
};

// The pipeline by hand; with `kill`, the tracker is killed with SIGKILL once
// its journal holds kKillAfterFrames tracked frames (counted with it held
// stopped, so the kill meets what was counted) and started again restarted.
PipelineRun runPipeline(const std::string& out, bool kill) {
  PipelineRun r;
  r.out = out;
  runCommand("mkdir -p " + out);
  const pid_t optimiser = spawnService("optimiser", out, "", "optimiser.log");
  pid_t tracker = spawnService("tracker", out, "", "tracker.log");
  const pid_t player = spawnService("player", out, "--dataset " + room(), "player.log");
  if (kill) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(kWaitS);
    while (std::chrono::steady_clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      if (::kill(tracker, SIGSTOP) != 0) break;  // ended: nothing to kill
      if (!stopped(tracker)) {                   // exiting (a zombie): let it go
        ::kill(tracker, SIGCONT);
        break;
      }
      r.frames_at_kill = journaledFrames(out).size();
      if (r.frames_at_kill >= static_cast<size_t>(kKillAfterFrames)) {
        ::kill(tracker, SIGKILL);
        r.tracker = rekon::test::waitForExit(tracker, kWaitS);
        tracker = spawnService("tracker", out, "--set tracker.restarted=true", "tracker_restarted.log");
        break;
      }
      ::kill(tracker, SIGCONT);
    }
  }
  r.player = rekon::test::waitForExit(player, kWaitS);
  (kill ? r.restarted : r.tracker) = rekon::test::waitForExit(tracker, kWaitS);
  r.optimiser = rekon::test::waitForExit(optimiser, kWaitS);
  return r;
}

double ateOf(const std::string& out) { return rekon::test::ateOf(room() + "/groundtruth.txt", out + "/trajectory.txt"); }

size_t poses(const std::string& trajectory) {
  std::ifstream in(trajectory);
  size_t n = 0;
  for (std::string l; std::getline(in, l);) n += !l.empty() && l[0] != '#';
  return n;
}

// Measured (2-core VM, loaded by two other sessions): uninterrupted ATE
// 0.2265 mm every time; killed after 45-49 frames and restarted, the first
// frame tracked by odometry against the killed instance's keyframe: 0.2265 mm
// in 3 of 3 runs (before the restart resumed odometry it relocalised the
// first frame: 0.2155-0.2365 mm in 9 runs). The bound, 0.002 mm above the
// uninterrupted run (1 % of it), leaves room for a kill between archiving a
// keyframe and publishing it (the restart makes that keyframe again); a
// relocalised first frame moves it by up to 0.010 mm.
TEST(TrackerRestartRun, KilledMidRunAndRestartedTheRunGoesOnToTheSameTrajectory) {
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  const PipelineRun base = runPipeline(dir / "uninterrupted", false);
  ASSERT_EQ(base.player, 0) << readText(base.out + "/player.log");
  ASSERT_EQ(base.tracker, 0) << readText(base.out + "/tracker.log");
  ASSERT_EQ(base.optimiser, 0) << readText(base.out + "/optimiser.log");
  const PipelineRun killed = runPipeline(dir / "killed", true);
  const std::string logs = "\nplayer:\n" + readText(killed.out + "/player.log") + "\ntracker (killed):\n" +
                           readText(killed.out + "/tracker.log") + "\ntracker (restarted):\n" +
                           readText(killed.out + "/tracker_restarted.log") + "\noptimiser:\n" +
                           readText(killed.out + "/optimiser.log");
  ASSERT_EQ(killed.tracker, 128 + SIGKILL) << "the tracker was not killed mid-run (" << killed.frames_at_kill
                                           << " frames journaled)" << logs;
  EXPECT_LT(killed.frames_at_kill, static_cast<size_t>(kFrames)) << logs;
  EXPECT_EQ(killed.player, 0) << logs;
  EXPECT_EQ(killed.restarted, 0) << logs;
  EXPECT_EQ(killed.optimiser, 0) << logs;
  const std::string restarted_log = readText(killed.out + "/tracker_restarted.log");
  EXPECT_NE(restarted_log.find("restarted: the journal holds"), std::string::npos) << logs;
  EXPECT_NE(restarted_log.find("first pose after the restart: frame " + std::to_string(killed.frames_at_kill)),
            std::string::npos)
      << logs;
  EXPECT_NE(restarted_log.find(", as before the kill"), std::string::npos) << logs;  // by odometry
  // Every frame tracked once, by one instance or the other.
  EXPECT_EQ(journaledFrames(killed.out).size(), static_cast<size_t>(kFrames)) << logs;
  EXPECT_EQ(poses(killed.out + "/trajectory.txt"), static_cast<size_t>(kFrames)) << logs;
  const double base_ate = ateOf(base.out), killed_ate = ateOf(killed.out);
  std::printf("ATE uninterrupted %.4f mm, killed after %zu frames and restarted %.4f mm\n", 1e3 * base_ate,
              killed.frames_at_kill, 1e3 * killed_ate);
  EXPECT_LT(killed_ate, base_ate + 0.000002) << logs;
}

}  // namespace
