// A live run that cannot be paused, and one whose device goes wrong:
//  - the player with pacing: live and CPU hogs beside every service drops
//    frames (newest wins), reports them, and still maps correctly;
//  - no device, and a recording that breaks mid-run (the fakenect library's
//    device "vanishing"): one line naming it, a clean end, outputs written.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/stat.h>
#include <sys/types.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

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
  // and 30 Hz no frame was dropped here, so this makes the consumers too
  // slow on any machine.
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
  EXPECT_EQ(jsonInt(player, "frames_captured"), 300);
  EXPECT_GT(jsonInt(player, "frames_dropped"), 0) << "a hog on two cores: the consumers cannot keep up";
  EXPECT_EQ(jsonInt(player, "frames_sent") + jsonInt(player, "frames_dropped"), 300);
  EXPECT_GT(jsonInt(player, "latency_samples"), 0);
  EXPECT_NE(readText(live + "/config.yaml").find("when_full: drop"), std::string::npos);
  const double paced = ateOf(data, dir / "paced"), dropped = ateOf(data, live);
  std::printf("ATE paced %.3f mm, live with hogs %.3f mm\n", 1e3 * paced, 1e3 * dropped);
  // Measured: paced 0.265 mm; live at 60 Hz with the hog 0.263-0.267 mm in 5 runs (6-19 frames
  // dropped), and 9.57 mm once while other tests loaded the machine too (25 dropped: a gap of
  // ~0.3 s of motion is near the edge of the tracker's basin, extrapolated or not). Without
  // the gap-scaled prediction it diverged (130 mm at 30 Hz with 43 dropped). 15 mm: still one
  // consistent map, not a divergence.
  EXPECT_LT(dropped, 0.015);
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
    const std::string camera_log = readText(dir / "out/camera.log");
    EXPECT_NE(camera_log.find(device.substr(0, device.find(':'))), std::string::npos) << camera_log;
    EXPECT_EQ(rekon::test::crashLines(out + camera_log), "") << out << camera_log;
    fs::remove_all(dir / "out");
  }
  EXPECT_EQ(runCommand(binDir() + "/rekon run --camera webcam --out " + (dir / "out"), &out), 1);
  EXPECT_NE(lastLine(out).find("unknown driver 'webcam'"), std::string::npos) << out;
  EXPECT_EQ(runCommand(binDir() + "/rekon run --camera freenect --dataset " + (dir / "x") + " --out " + (dir / "out"), &out), 1);
  EXPECT_NE(lastLine(out).find("one of --dataset DIR or --camera DEVICE"), std::string::npos) << out;
}

// A recording cut mid-frame is, to rekon, a device that vanished: the frames
// before it are tracked and mapped, the run ends cleanly with every output,
// exits 1, and its last line names the file.
TEST(LiveErrors, RecordingTruncatedMidFrameEndsTheRunCleanlyWithOutputs) {
  rekon::test::TempDir dir;
  const std::string data = dir / "room", fk = dir / "fakenect", out_dir = dir / "live";
  std::string out;
  ASSERT_EQ(runCommand(binDir() + "/rekon synth --scene room --frames 60 --out " + data), 0);
  ASSERT_EQ(runCommand(binDir() + "/rekon-fakenect-write --dataset " + data + " --out " + fk + " --slowdown 2", &out), 0)
      << out;
  // The depth image of the 40th frame, cut in half.
  std::ifstream index(fk + "/INDEX.txt");
  std::string line, cut;
  for (int depth_seen = 0; std::getline(index, line);) {
    if (line.rfind("d-", 0) == 0 && ++depth_seen == 40) cut = line;
  }
  ASSERT_FALSE(cut.empty());
  fs::resize_file(fk + "/" + cut, fs::file_size(fk + "/" + cut) / 2);

  const int rc = runCommand("FAKENECT_PATH=" + fk + " LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect " + inNetns() +
                                " timeout 300 " + binDir() + "/rekon run --camera freenect --out " + out_dir,
                            &out);
  EXPECT_EQ(rc, 1) << out;
  EXPECT_NE(lastLine(out).find(cut), std::string::npos) << out;
  for (const char* f : {"trajectory.txt", "mesh.ply", "stats.json", "camera.yaml"}) {
    EXPECT_TRUE(fs::exists(out_dir + "/" + f)) << f << "\n" << out;
  }
  const std::string camera = readText(out_dir + "/camera_stats.json");
  EXPECT_GE(jsonInt(camera, "frames_captured"), 35) << camera;
  EXPECT_LE(jsonInt(camera, "frames_captured"), 39) << camera;
  EXPECT_NE(camera.find("device lost"), std::string::npos) << camera;
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
