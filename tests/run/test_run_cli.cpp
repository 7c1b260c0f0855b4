// `rekon run` as a user meets it (issue 27): bad input is refused before any
// service starts, in one line, leaving nothing behind; a folder that holds a
// run is not overwritten by accident; Ctrl-C is recorded in stats.json.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <signal.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <thread>

#include "test_support.hpp"

namespace {

using rekon::test::binDir;
using rekon::test::readText;
using rekon::test::runCommand;
namespace fs = std::filesystem;

std::string rekonBin() { return binDir() + "/rekon"; }

// A synthetic room of `frames` frames in dir/room (a few seconds to write and to run).
std::string room(const rekon::test::TempDir& dir, int frames) {
  const std::string data = dir / "room";
  EXPECT_EQ(runCommand("timeout 120 " + rekonBin() + " synth --scene room --frames " + std::to_string(frames) + " --out " +
                       data + " > /dev/null 2>&1"), 0);
  return data;
}

struct Refusal {
  std::string args, says;
};

// Each is refused with one error line naming the thing, before any service
// starts and before --out is created. Before issue 27 the bad values, the
// empty dataset and the unknown driver were found only after every service
// had started, leaving an empty run in --out.
TEST(RunCli, BadInputIsRefusedBeforeAnythingStartsOrIsCreated) {
  rekon::test::TempDir dir;
  const std::string data = room(dir, 5);
  fs::create_directories(dir / "empty");
  // A dataset whose depth images are gone, and a port another program holds.
  fs::copy(data, dir / "no_depth", fs::copy_options::recursive);
  fs::remove_all(dir / "no_depth/depth");
  const rekon::test::ListeningSocket busy;
  const std::vector<Refusal> refusals = {
      {"--dataset " + data + " --set mapper.kappa=abc", "config key mapper.kappa = 'abc' is not a number"},
      {"--dataset " + data + " --set volume.voxel_size=-1", "volume.voxel_size = -1"},
      {"--dataset " + data + " --set mapper.use_store=maybe", "mapper.use_store = 'maybe' is not true or false"},
      {"--dataset " + data + " --set player.rate=fast", "player.rate 'fast'"},
      {"--dataset " + (dir / "empty"), "camera.yaml"},
      {"--dataset " + (dir / "nowhere"), "dataset folder not found"},
      {"--camera kinect", "unknown driver 'kinect'"},
      // Issue 45: these were found only after every service had started.
      {"--camera freenect", "no freenect device is connected"},  // no Kinect on any machine here
      {"--camera freenect --record " + data, "already holds a recording (rgb.txt)"},
      {"--camera openni2:" + (dir / "none.oni"), "OpenNI2 recording not found"},
      {"--dataset " + (dir / "no_depth"), "of the 5 depth images depth.txt lists are missing"},
      {"--dataset " + data + " --view --set viewer.port=" + std::to_string(busy.port()), "viewer.port " +
           std::to_string(busy.port()) + " on 127.0.0.1 is in use"},
      {"--dataset " + data + " --camera openni2", "give one of them"},
  };
  for (const Refusal& r : refusals) {
    std::string out;
    const int rc = runCommand("timeout 60 " + rekonBin() + " run " + r.args + " --out " + (dir / "out") + " 2>&1", &out);
    EXPECT_EQ(rc, 1) << r.args << "\n" << out;
    EXPECT_NE(out.find(r.says), std::string::npos) << r.args << "\n" << out;
    EXPECT_EQ(out.find("started rekon-"), std::string::npos) << r.args << "\n" << out;
    EXPECT_FALSE(fs::exists(dir / "out")) << r.args;
    // One line, the program named once ("rekon run: error: rekon run: ..." before).
    EXPECT_TRUE(std::regex_match(out, std::regex("rekon run: error: [^\n]*\n"))) << out;
    EXPECT_EQ(out.find("rekon run: error: rekon run"), std::string::npos) << out;
  }
  std::string out;
  runCommand(rekonBin() + " run --dataset " + data + " --out " + (dir / "out") + " --no-such-option 2>&1", &out);
  EXPECT_EQ(out, "rekon run: error: unknown option --no-such-option; see rekon run --help\n");
}

// A second run into the folder of a first is refused and the first run's
// outputs stay as they were; with --force the earlier run's files go first,
// so a run that writes no mesh lists none.
TEST(RunCli, AFolderHoldingARunIsRefusedUnlessForced) {
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  const std::string data = room(dir, 20);
  const std::string run = "timeout 120 " + rekonBin() + " run --dataset " + data + " --out " + (dir / "out");
  ASSERT_EQ(runCommand(run + " > " + (dir / "first.log") + " 2>&1"), 0) << readText(dir / "first.log");
  ASSERT_TRUE(fs::exists(dir / "out/mesh.ply"));
  // Not a terminal: the progress as plain lines, the last one the whole run's,
  // whose realtime factor is stats.json's (issue 45: they were 1.78 and 1.22).
  std::smatch last;
  const std::string first_log = readText(dir / "first.log");
  ASSERT_TRUE(std::regex_search(first_log, last, std::regex(R"(\nframe 20/20 \(100 %\), [0-9.]+ fps, ([0-9.]+)x realtime\n)")))
      << first_log;
  std::smatch factor;
  const std::string stats = readText(dir / "out/stats.json");
  ASSERT_TRUE(std::regex_search(stats, factor, std::regex(R"("realtime_factor": ([0-9.]+))"))) << stats;
  EXPECT_EQ(last[1].str(), fmt::format("{:.2f}", std::stod(factor[1].str()))) << first_log << stats;
  const auto mesh_time = fs::last_write_time(dir / "out/mesh.ply");

  std::string out;
  EXPECT_EQ(runCommand(run + " 2>&1", &out), 1);
  EXPECT_NE(out.find("holds an earlier run"), std::string::npos) << out;
  EXPECT_NE(out.find("--force"), std::string::npos) << out;
  EXPECT_EQ(fs::last_write_time(dir / "out/mesh.ply"), mesh_time);

  // Without the mapper this run writes no mesh: the first run's must neither stay nor be listed.
  // The report's folder goes too (issue 45: 26 files of it stayed).
  fs::create_directories(dir / "out/report");
  std::ofstream(dir / "out/report/plot.svg") << "<svg/>";
  EXPECT_EQ(runCommand(run + " --force --set run.services=[player,tracker,optimiser] 2>&1", &out), 0) << out;
  EXPECT_FALSE(fs::exists(dir / "out/mesh.ply")) << out;
  EXPECT_FALSE(fs::exists(dir / "out/report")) << out;
  EXPECT_EQ(out.find("mesh.ply"), std::string::npos) << out;
  EXPECT_NE(out.find("trajectory.txt"), std::string::npos) << out;
}

// A service that cannot start (here its log path is a folder; a binary
// being relinked at that moment did the same) fails the run in one line and
// stops those started: the run used to wait forever for the child that never ran.
TEST(RunCli, AServiceThatCannotStartFailsTheRunInsteadOfHanging) {
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  const std::string data = room(dir, 5);
  fs::create_directories(dir / "out/mapper.log/in_the_way");
  std::string out;
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(runCommand("timeout 60 " + rekonBin() + " run --dataset " + data + " --out " + (dir / "out") + " 2>&1", &out), 1)
      << out;
  EXPECT_NE(out.find("mapper.log: cannot open log"), std::string::npos) << out;
  // Those started before it are stopped at once: seconds, not the 60 s timeout (1.4 s measured, the room included).
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 30.0);
}

// player.first_frame and max_frames: the progress counts the frames played
// (it said "frame 613/500 (123 %)" for first_frame 500, max_frames 500).
TEST(RunCli, ProgressCountsTheFramesPlayedFromTheFirst) {
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  const std::string data = room(dir, 20);
  std::string out;
  ASSERT_EQ(runCommand("timeout 120 " + rekonBin() + " run --dataset " + data + " --out " + (dir / "out") +
                       " --set player.first_frame=12 --set player.max_frames=6 2>&1", &out), 0) << out;
  EXPECT_TRUE(std::regex_search(out, std::regex(R"(\nframe 6/6 \(100 %\), [0-9.]+ fps, [0-9.]+x realtime\n)"))) << out;
  EXPECT_FALSE(std::regex_search(out, std::regex(R"(frame ([7-9]|[1-9][0-9]+)/6)"))) << out;
}

// Ctrl-C mid-run: exit 130 and stats.json says the run was interrupted.
TEST(RunCli, AnInterruptedRunIsMarkedInStats) {
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  const std::string data = room(dir, 150);
  const pid_t run = rekon::test::spawnShell("exec " + rekonBin() + " run --set player.rate=1 --dataset " + data + " --out " +
                                            (dir / "out") + " > " + (dir / "run.log") + " 2>&1");
  const auto start = std::chrono::steady_clock::now();
  while (readText(dir / "run.log").find("started rekon-player") == std::string::npos &&
         std::chrono::steady_clock::now() - start < std::chrono::seconds(30)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  std::this_thread::sleep_for(std::chrono::seconds(2));  // 150 frames at their recorded rate: 5 s
  kill(run, SIGINT);
  EXPECT_EQ(rekon::test::waitForExit(run, 60), 130) << readText(dir / "run.log");
  EXPECT_NE(readText(dir / "out/stats.json").find("\"interrupted\": true"), std::string::npos) << readText(dir / "out/stats.json");
  // The last progress line says so, with no ETA for a run that is over.
  const std::string log = readText(dir / "run.log");
  EXPECT_TRUE(std::regex_search(log, std::regex(R"(\nframe [0-9]+/150 \([0-9]+ %\)[^\n]* \(interrupted\)\n)"))) << log;
  EXPECT_FALSE(std::regex_search(log, std::regex(R"(ETA[^\n]*\(interrupted\))"))) << log;
}

}  // namespace

namespace {

// Issue 27: --version with the git revision and build type; every
// subcommand's usage names the command a user types (not rekon-viewer or
// rekon-listener) and run, demo, synth, render show examples; the wrapper
// lists its own commands too.
TEST(RekonCli, VersionHelpAndExamples) {
  std::string out;
  ASSERT_EQ(runCommand(rekonBin() + " --version", &out), 0) << out;
  EXPECT_TRUE(std::regex_match(out, std::regex("rekon, git revision [0-9a-f]{12}(\\+local changes)?, [A-Za-z]+ build\n"))) << out;
  for (const char* c : {"eval", "render", "fuse", "odometry", "synth", "run", "cameras", "view", "demo", "remesh", "export",
                        "keyframes", "listen", "report", "bench"}) {
    runCommand(rekonBin() + " " + c + " --help 2>&1", &out);
    EXPECT_EQ(out.rfind(std::string("usage: rekon ") + c, 0), 0u) << out.substr(0, 200);
  }
  for (const char* c : {"run", "demo", "synth", "render", "eval", "remesh", "export"}) {
    runCommand(rekonBin() + " " + c + " --help 2>&1", &out);
    EXPECT_TRUE(std::regex_search(out, std::regex(std::string("\nexamples:\n  rekon ") + c + "[ \n]"))) << out;
  }
  ASSERT_EQ(runCommand(rekon::test::sourceDir() + "/tools/rekon --help", &out), 0) << out;
  for (const char* c : {"\n  demo", "\n  test", "\n  setup", "\n  deps", "\n  stress", "\n  sanitize", "\n  fuzz", "tools/gpu-check",
                        "\n  run ", "\n  report "}) {
    EXPECT_NE(out.find(c), std::string::npos) << c << " not in tools/rekon --help:\n" << out;
  }
  // Each command once (demo was listed by the script and again by the binary).
  EXPECT_EQ(out.find("\n  demo "), out.rfind("\n  demo ")) << out;
  // The script's own commands answer --help with their usage and do nothing
  // else: no apt-get, no configure or build (REKON_BUILD_DIR stays absent),
  // no fuzzing (`fuzz --help` started an unbounded run).
  rekon::test::TempDir dir;
  for (const char* c : {"demo", "test", "setup", "deps", "stress", "sanitize", "fuzz"}) {
    EXPECT_EQ(runCommand("REKON_BUILD_DIR=" + (dir / "nobuild") + " timeout 20 " + rekon::test::sourceDir() + "/tools/rekon " +
                         c + " --help 2>&1", &out), 0) << c << ": " << out;
    EXPECT_EQ(out.rfind(std::string("usage: tools/rekon ") + c, 0), 0u) << c << ": " << out;
    EXPECT_FALSE(fs::exists(dir / "nobuild")) << c;
  }
}

// A mistyped command, option or config key gets the nearest one suggested, as git does.
TEST(RekonCli, TyposGetTheNearestNameSuggested) {
  std::string out;
  EXPECT_EQ(runCommand(rekonBin() + " runn 2>&1", &out), 2);
  EXPECT_NE(out.find("unknown command 'runn'; did you mean 'run'?"), std::string::npos) << out;
  EXPECT_EQ(runCommand(rekonBin() + " run --dataest x --out y 2>&1", &out), 1);
  EXPECT_NE(out.find("unknown option --dataest; did you mean --dataset?"), std::string::npos) << out;
  rekon::test::TempDir dir;
  const std::string data = room(dir, 3);
  EXPECT_EQ(runCommand(rekonBin() + " run --dataset " + data + " --out " + (dir / "out") + " --set volume.voxelsize=0.02 2>&1",
                       &out), 1);
  EXPECT_NE(out.find("did you mean 'volume.voxel_size'?"), std::string::npos) << out;
  // Nothing near: no suggestion.
  EXPECT_EQ(runCommand(rekonBin() + " frobnicate 2>&1", &out), 2);
  EXPECT_EQ(out.find("did you mean"), std::string::npos) << out;
}

}  // namespace
