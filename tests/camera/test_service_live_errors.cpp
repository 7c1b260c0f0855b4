// A live run that cannot be paused, and one whose device goes wrong:
//  - the player with pacing: live and CPU hogs beside every service drops
//    frames (newest wins) or skips those whose time passed, reports both,
//    stays on its clock, and still maps correctly;
//  - no device, and a recording that breaks mid-run (the fakenect library's
//    device "vanishing"): one line naming it, a clean end, outputs written.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/stat.h>
#include <sys/types.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <thread>

#include "rekon/common/config.hpp"
#include "test_support.hpp"

namespace {

namespace fs = std::filesystem;
using rekon::test::binDir;
using rekon::test::jsonInt;
using rekon::test::readText;
using rekon::test::runCommand;

using rekon::test::inNetns;

using rekon::test::valueAfter;

double ateOf(const std::string& data, const std::string& run) {
  std::string out;
  runCommand(binDir() + "/rekon eval traj " + data + "/groundtruth.txt " + run + "/trajectory.txt", &out);
  return valueAfter(out, "ate_rmse_m");
}

// The last line of a command's output.
std::string lastLine(const std::string& output) {
  std::string s = output;
  while (!s.empty() && s.back() == '\n') s.pop_back();
  const auto nl = s.rfind('\n');
  return nl == std::string::npos ? s : s.substr(nl + 1);
}

}  // namespace

TEST(LivePacing, PlayerLiveAtTwiceTheRecordedRateWithACpuHogDropsFramesAndStillMaps) {
  rekon::test::TempDir dir;
  const std::string data = dir / "room";
  ASSERT_EQ(runCommand(binDir() + "/rekon synth --scene room --frames 300 --out " + data), 0);
  std::string out;
  ASSERT_EQ(runCommand(inNetns() + " timeout 300 " + binDir() + "/rekon run --dataset " + data + " --out " + (dir / "paced"), &out), 0)
      << out;
  // A busy loop beside the services for as long as the live run lasts, and
  // the room played live at twice its recorded rate (60 Hz): with one hog
  // and 30 Hz no frame was dropped here, so this makes the consumers, or the
  // player itself, too slow on any machine.
  const std::string live = dir / "live";
  const pid_t hog = rekon::test::spawnShell("exec sh -c 'while :; do :; done'");
  const int rc = runCommand(inNetns() + " timeout 300 " + binDir() + "/rekon run --dataset " + data + " --out " + live +
                                " --set player.rate=2 --set player.pacing=live",
                            &out);
  kill(hog, SIGKILL);
  rekon::test::waitForExit(hog, 10);
  ASSERT_EQ(rc, 0) << out;
  const std::string player = readText(live + "/player_stats.json");
  std::printf("player: %s\nmapper peak RSS %lld MB, tracker %lld MB\n", player.c_str(),
              jsonInt(readText(live + "/mapper_stats.json"), "peak_rss_mb"),
              jsonInt(readText(live + "/tracker_stats.json"), "peak_rss_mb"));
  // Whether the consumers fall behind (frames the player drops when they
  // are not ready, or the mapper drops beyond its queue: rekon run sets
  // mapper.when_full drop behind a live source) or the player does (frames
  // skipped for lateness) depends on the machine and its load; that one of
  // them does, does not. On a fast 2-core VM only the mapper dropped (4
  // runs: 28-53 of 300, the player none): counting the player alone failed
  // there.
  const long long captured = jsonInt(player, "frames_captured"), skipped = jsonInt(player, "frames_skipped_late"),
                  dropped = jsonInt(player, "frames_dropped"), sent = jsonInt(player, "frames_sent");
  const long long mapper_dropped = jsonInt(readText(live + "/mapper_stats.json"), "frames_dropped");
  EXPECT_GT(skipped + dropped + mapper_dropped, 0) << "a hog on two cores: the consumers or the player cannot keep up";
  EXPECT_GE(skipped, 0);
  EXPECT_EQ(captured + skipped, 300) << "every frame is taken on time or skipped for lateness";
  EXPECT_EQ(sent + dropped, captured);
  EXPECT_GT(jsonInt(player, "latency_samples"), 0);
  // A camera does not slow down: the 10 s sequence at twice its rate is
  // played in 5 s, the last frame (due at 4.983 s) going out at most one or
  // two frame decodes late. Measured 5.01-5.27 s in 6 runs beside two more
  // hogs (and other work), where one decode took 0.09-0.70 s; 0.4 s is 24
  // frame periods at 60 Hz, far from the 9 s behind of a player that
  // decoded every frame.
  const double wall = rekon::test::jsonNumber(player, "wall_seconds");
  const double due = rekon::test::jsonNumber(player, "sequence_seconds") / 2.0;
  EXPECT_NEAR(wall, due, 0.4) << player;
  EXPECT_NE(readText(live + "/config.yaml").find("when_full: drop"), std::string::npos);
  EXPECT_NE(readText(live + "/config.yaml").find("loop_when_behind: fewer"), std::string::npos);
  const rekon::Config live_config = rekon::Config::load(live + "/config.yaml");
  EXPECT_EQ(live_config.getInt("mapper.nice"), 10);
  EXPECT_EQ(live_config.getInt("optimiser.nice"), 10);
  const double paced = ateOf(data, dir / "paced"), dropped_ate = ateOf(data, live);
  std::printf("ATE paced %.3f mm, live with hogs %.3f mm\n", 1e3 * paced, 1e3 * dropped_ate);
  // Measured: paced 0.265 mm; live at 60 Hz with the hog 0.263-0.267 mm in 5 runs (6-19 frames
  // dropped), and 9.57 mm once while other tests loaded the machine too (25 dropped: a gap of
  // ~0.3 s of motion is near the edge of the tracker's basin, extrapolated or not). Without
  // the gap-scaled prediction it diverged (130 mm at 30 Hz with 43 dropped). 15 mm: still one
  // consistent map, not a divergence.
  EXPECT_LT(dropped_ate, 0.015);
}

// A player that cannot decode at its rate is a camera on a starved machine:
// the room at 100 times its recorded rate has its 300 frames due within
// 0.1 s, and one frame takes milliseconds to load and decode (on any
// machine: a 640x480 RGB and a 16-bit PNG). It skips the frames whose time
// has passed, never decoding them, counts them, and ends on its clock: the
// last frame goes out at most two decodes (the one under way when it fell
// due, and its own) and two frame periods late. Decoding ahead on two
// threads, the skipped frames are not decoded either: a skip abandons at
// most what was prepared (two frames) and never waits for it.
TEST(LivePacing, PlayerBehindItsClockSkipsTheLateFramesAndEndsOnTime) {
  rekon::test::TempDir dir;
  const std::string data = dir / "room";
  ASSERT_EQ(runCommand(binDir() + "/rekon synth --scene room --frames 300 --out " + data), 0);
  constexpr double kRate = 100, kPeriodS = 1.0 / (30.0 * kRate);
  for (const int threads : {0, 2}) {
    SCOPED_TRACE("player.decode_threads=" + std::to_string(threads));
    const std::string run = dir / ("player_" + std::to_string(threads));
    std::string out;
    // No consumers: nothing to acknowledge, the player alone against its clock.
    ASSERT_EQ(runCommand(inNetns() + " timeout 120 " + binDir() + "/rekon-player --dataset " + data + " --out " + run +
                             " --rate 100 --set player.pacing=live --set player.wait_for=[] --set player.decode_threads=" +
                             std::to_string(threads),
                         &out),
              0)
        << out;
    const std::string player = readText(run + "/player_stats.json");
    std::printf("player: %s\n", player.c_str());
    const long long captured = jsonInt(player, "frames_captured"), skipped = jsonInt(player, "frames_skipped_late"),
                    unused = jsonInt(player, "frames_decoded_unused");
    EXPECT_GT(skipped, 0) << player;
    EXPECT_EQ(captured + skipped, 300) << player;
    EXPECT_GE(unused, 0) << player;
    EXPECT_LE(unused, threads * captured) << player;
    EXPECT_LT(captured + unused, 300) << "frames skipped are never decoded\n" << player;
    // The same counts go to source_counts.csv as they come (rekon bench longrun's frames per minute): its
    // last row, at the end, holds the frames due, sent, dropped and skipped.
    const std::string last_row = lastLine(readText(run + "/source_counts.csv"));
    EXPECT_EQ(last_row.substr(last_row.find(',') + 1, last_row.rfind(',') - last_row.find(',')),
              "300," + std::to_string(jsonInt(player, "frames_sent")) + "," +
                  std::to_string(jsonInt(player, "frames_dropped")) + "," + std::to_string(skipped) + ",")
        << last_row;
    const double decode_s = rekon::test::jsonNumber(player, "decode_s_max");
    // 20 ms for the rest of one iteration (waking, offering) on a loaded machine.
    const double bound_s = 2.0 * decode_s + 2.0 * kPeriodS + 0.02;
    EXPECT_LE(rekon::test::jsonNumber(player, "behind_clock_s_end"), bound_s) << player;
    EXPECT_LE(rekon::test::jsonNumber(player, "wall_seconds"),
              rekon::test::jsonNumber(player, "sequence_seconds") / kRate + bound_s)
        << player;
  }
}

TEST(LiveErrors, NoDeviceIsOneLineNamingIt) {
  rekon::test::TempDir dir;
  std::string out;
  // No Kinect and no OpenNI2 device is attached to any machine here.
  for (const std::string device : {"freenect:5", "openni2:/nonexistent/recording.oni"}) {
    const int rc = runCommand(inNetns() + " timeout 120 " + binDir() + "/rekon run --camera " + device + " --out " +
                                  (dir / "out"),
                              &out);
    EXPECT_EQ(rc, 1) << out;
    // Found before anything starts (issue 45): one line naming the device, no run folder.
    EXPECT_NE(lastLine(out).find("--camera " + device), std::string::npos) << out;
    EXPECT_EQ(out.find("started rekon-"), std::string::npos) << out;
    EXPECT_FALSE(fs::exists(dir / "out")) << out;
    EXPECT_EQ(rekon::test::crashLines(out), "") << out;
    // rekon-camera started by hand says so itself.
    EXPECT_EQ(runCommand(inNetns() + " timeout 60 " + binDir() + "/rekon-camera --device " + device +
                             " --set camera.wait_for=[] 2>&1", &out),
              1)
        << out;
    EXPECT_NE(out.find(device.substr(0, device.find(':'))), std::string::npos) << out;
    EXPECT_EQ(rekon::test::crashLines(out), "") << out;
  }
  EXPECT_EQ(runCommand(binDir() + "/rekon run --camera webcam --out " + (dir / "out"), &out), 1);
  EXPECT_NE(lastLine(out).find("unknown driver 'webcam'"), std::string::npos) << out;
  EXPECT_EQ(runCommand(binDir() + "/rekon run --camera freenect --dataset " + (dir / "x") + " --out " + (dir / "out"), &out), 1);
  EXPECT_NE(lastLine(out).find("--dataset plays a recorded sequence and --camera runs a live camera; give one of them"), std::string::npos) << out;
}

// The room's 60 frames as a fakenect recording in `fk` (slowed down 2x);
// false (a test failure with the tools' output) when it could not be made.
bool fakenectRoom(const rekon::test::TempDir& dir, const std::string& fk) {
  std::string out;
  if (runCommand(binDir() + "/rekon synth --scene room --frames 60 --out " + (dir / "room"), &out) != 0 ||
      runCommand(binDir() + "/rekon-fakenect-write --dataset " + (dir / "room") + " --out " + fk + " --slowdown 2", &out) != 0) {
    ADD_FAILURE() << out;
    return false;
  }
  return true;
}

// fakenectRoom whose 40th depth image is cut in half (the whole one kept as
// dir/whole.pgm); returns that file's name ("" on failure).
std::string truncatedRecording(const rekon::test::TempDir& dir, const std::string& fk) {
  if (!fakenectRoom(dir, fk)) return "";
  std::ifstream index(fk + "/INDEX.txt");
  std::string line, cut;
  for (int depth_seen = 0; std::getline(index, line);) {
    if (line.rfind("d-", 0) == 0 && ++depth_seen == 40) cut = line;
  }
  if (!cut.empty()) {
    fs::copy_file(fk + "/" + cut, dir / "whole.pgm");
    fs::resize_file(fk + "/" + cut, fs::file_size(fk + "/" + cut) / 2);
  }
  return cut;
}

std::string runFakenect(const std::string& fk, const std::string& out_dir, const std::string& sets) {
  return "FAKENECT_PATH=" + fk + " LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect " + inNetns() + " timeout 300 " +
         binDir() + "/rekon run --camera freenect --out " + out_dir + " " + sets;
}

// A recording cut mid-frame is, to rekon, a device that vanished and stays
// away: rekon-camera tries to reopen it for camera.reconnect_timeout_s, then
// the frames before it are tracked and mapped, the run ends cleanly with
// every output, exits 1, and its last line names the file.
TEST(LiveErrors, RecordingTruncatedMidFrameEndsTheRunCleanlyWithOutputs) {
  rekon::test::TempDir dir;
  const std::string fk = dir / "fakenect", out_dir = dir / "live";
  const std::string cut = truncatedRecording(dir, fk);
  ASSERT_FALSE(cut.empty());
  std::string out;
  const int rc = runCommand(runFakenect(fk, out_dir, "--set camera.reconnect_timeout_s=2"), &out);
  EXPECT_EQ(rc, 1) << out;
  EXPECT_NE(readText(out_dir + "/camera.log").find("reopening it for up to 2 s"), std::string::npos);
  EXPECT_NE(lastLine(out).find(cut), std::string::npos) << out;
  for (const char* f : {"trajectory.txt", "mesh.ply", "stats.json", "camera.yaml"}) {
    EXPECT_TRUE(fs::exists(out_dir + "/" + f)) << f << "\n" << out;
  }
  const std::string camera = readText(out_dir + "/camera_stats.json");
  const long long delivered = jsonInt(camera, "frames_captured") + jsonInt(camera, "frames_skipped_late");
  EXPECT_GE(delivered, 35) << camera;
  EXPECT_LE(delivered, 39) << camera;
  EXPECT_NE(camera.find("device lost"), std::string::npos) << camera;
  EXPECT_EQ(jsonInt(camera, "outages"), 0) << camera;
  EXPECT_EQ(rekon::test::crashLines(out + readText(out_dir + "/camera.log")), "");
}

// The device back while rekon-camera reopens it (issue 48): the recording
// is whole again before the first attempt (camera.reconnect_wait_s 2 s after
// the loss; later attempts would only make the outage longer), fakenect goes
// on from where it stopped, as a device goes on streaming, and the scan
// completes: exit 0, one outage counted, every frame of the recording
// captured (or skipped late) once.
TEST(LiveErrors, ADeviceThatComesBackIsReopenedAndTheScanGoesOn) {
  rekon::test::TempDir dir;
  const std::string fk = dir / "fakenect", out_dir = dir / "live";
  const std::string cut = truncatedRecording(dir, fk);
  ASSERT_FALSE(cut.empty());
  std::string out;
  int rc = -1;
  std::thread run([&] { rc = runCommand(runFakenect(fk, out_dir, "--set camera.reconnect_wait_s=2"), &out); });
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (readText(out_dir + "/camera.log").find("reopening it") == std::string::npos &&
         std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  fs::copy_file(dir / "whole.pgm", fk + "/" + cut, fs::copy_options::overwrite_existing);
  run.join();
  ASSERT_EQ(rc, 0) << out;
  const std::string camera = readText(out_dir + "/camera_stats.json");
  EXPECT_EQ(jsonInt(camera, "outages"), 1) << camera;
  EXPECT_EQ(jsonInt(camera, "frames_captured") + jsonInt(camera, "frames_skipped_late"), 60) << camera;
  EXPECT_NE(camera.find("\"end\": \"end of stream\""), std::string::npos) << camera;
  EXPECT_NE(readText(out_dir + "/camera.log").find("is back after"), std::string::npos);
  const std::string stats = readText(out_dir + "/stats.json");
  EXPECT_EQ(jsonInt(stats, "frames"), jsonInt(camera, "frames_sent")) << stats;
  EXPECT_EQ(rekon::test::crashLines(out + readText(out_dir + "/camera.log")), "");
}

// `rekon cameras`: nothing attached here is exit 1 with what to do; the
// fakenect library replaying a recording is one Kinect with its modes.
TEST(LiveErrors, CamerasListsWhatTheDriversSee) {
  rekon::test::TempDir dir;
  std::string out;
  EXPECT_EQ(runCommand(binDir() + "/rekon cameras", &out), 1) << out;
  EXPECT_NE(out.find("no camera found"), std::string::npos) << out;
  ASSERT_EQ(runCommand(binDir() + "/rekon synth --scene room --frames 2 --out " + (dir / "room")), 0);
  ASSERT_EQ(runCommand(binDir() + "/rekon-fakenect-write --dataset " + (dir / "room") + " --out " + (dir / "fk")), 0);
  EXPECT_EQ(runCommand("FAKENECT_PATH=" + (dir / "fk") + " LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect " + binDir() +
                           "/rekon cameras",
                       &out),
            0)
      << out;
  EXPECT_NE(out.find("freenect:0"), std::string::npos) << out;
  EXPECT_NE(out.find("depth 640x480@30 11-bit"), std::string::npos) << out;
}

namespace {

// The restarted camera (a new process: fakenect plays its recording from the
// start again, as a camera sends what it sees now) numbers its frames after
// the newest its consumers have (issue 48): an id from 0 again would be taken
// for a frame they had, and the scan would stop there.
TEST(LiveErrors, AKilledCameraIsRestartedAndItsFrameIdsGoOn) {
  rekon::test::TempDir dir;
  const std::string fk = dir / "fakenect", out_dir = dir / "live";
  ASSERT_TRUE(fakenectRoom(dir, fk));
  std::string out;
  const int rc = runCommand("FAKENECT_PATH=" + fk + " LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect " + inNetns() + " " +
                                rekon::test::sourceDir() + "/tests/faults/kill_during_run.sh " + binDir() + " camera 1 " +
                                out_dir + " --camera freenect",
                            &out);
  ASSERT_NE(out.find("killed rekon-camera"), std::string::npos) << out;
  ASSERT_EQ(rc, 0) << out << readText(out_dir + "/run.out");
  EXPECT_NE(readText(out_dir + "/stats.json").find("\"restarts\": {\"camera\":1}"), std::string::npos);
  const std::string camera = readText(out_dir + "/camera_stats.json");
  const long long first = jsonInt(camera, "restarted_at_frame");
  EXPECT_GT(first, 0) << camera;
  // Every frame of both instances tracked, each id once: the first one's
  // frames before `first`, then the restart's whole recording after them.
  std::ifstream trajectory(out_dir + "/trajectory.txt");
  std::set<std::string> stamps;
  size_t poses = 0;
  for (std::string line; std::getline(trajectory, line);) {
    if (line.empty() || line[0] == '#') continue;
    ++poses;
    stamps.insert(line.substr(0, line.find(' ')));
  }
  EXPECT_EQ(stamps.size(), poses) << "a timestamp twice";
  EXPECT_GE(poses, static_cast<size_t>(first + jsonInt(camera, "frames_sent") - 2)) << camera;
}

}  // namespace
