// `rekon run --continue` (issue 18): the synthetic room's first 300 frames
// with --session, then frames 300-599 continuing it, against one run of all
// 600; and sessions that must be refused (another camera, a newer format,
// damaged files, a scene the session never saw) with one line, the session
// untouched.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>

#include "rekon/common/pose.hpp"
#include "test_support.hpp"

namespace {

namespace fs = std::filesystem;
using rekon::test::ateOf;
using rekon::test::binDir;
using rekon::test::jsonInt;
using rekon::test::readText;
using rekon::test::runCommand;
using rekon::test::valueAfter;

constexpr int kFrames = 600, kFirstRun = 300;

// Every file of a folder with its content: a session before and after a refused run.
std::map<std::string, std::string> contents(const std::string& dir) {
  std::map<std::string, std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) out[fs::relative(e.path(), dir).string()] = readText(e.path().string());
  return out;
}

// `rekon run` of `args` in the test's network namespace; its output appended to `log`.
int runInNetns(const std::string& args, std::string* log) {
  return runCommand(rekon::test::inNetns() + " timeout 300 " + binDir() + "/rekon run " + args, log);
}

// CORR of a run's (or an export's) mesh against the room's exact surface, moved by the ATE alignment.
double corrOf(const std::string& data, const std::string& run) {
  std::string out;
  runCommand(binDir() + "/rekon eval surface " + run + "/mesh.ply " + data + "/mesh_gt.ply --est-trajectory " + run +
                 "/trajectory.txt --gt-trajectory " + data + "/groundtruth.txt",
             &out);
  return valueAfter(out, "corr_m");
}

// Measured: frame 300 is not placed (12 frames past the first run's last
// keyframe, outside the coarse level's basin from every guess), frame 301 is,
// against that keyframe. The exported session (both runs, one alignment for
// all frames) has ATE 0.304 mm and CORR 0.933 mm; the single run 0.287 and
// 0.925 mm (1.06x and 1.01x). Bounds: 1.5x each, and at most 10 frames lost
// to relocalisation (1 measured).
TEST(SessionContinue, TwoRunsMakeOneTrajectoryAndOneMapAsGoodAsOneRun) {
  rekon::test::TempDir dir;
  const std::string room = dir / "room", session = dir / "session";
  ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene room --frames " + std::to_string(kFrames) +
                       " --out " + room), 0);
  std::string log;
  ASSERT_EQ(runInNetns("--dataset " + room + " --out " + (dir / "single"), &log), 0) << log;
  ASSERT_EQ(runInNetns("--dataset " + room + " --out " + (dir / "first") + " --session " + session +
                       " --set player.max_frames=" + std::to_string(kFirstRun), &log), 0) << log;
  ASSERT_EQ(runInNetns("--dataset " + room + " --out " + (dir / "second") + " --continue " + session +
                       " --set player.first_frame=" + std::to_string(kFirstRun), &log), 0) << log;
  ASSERT_EQ(runCommand(binDir() + "/rekon export " + session + " --out " + (dir / "export"), &log), 0) << log;

  const std::string tracker = readText(dir / "second/tracker_stats.json");
  EXPECT_GE(jsonInt(tracker, "relocalisations"), 1) << tracker;
  EXPECT_NE(tracker.find(R"("first_frame":300,)"), std::string::npos) << tracker;
  EXPECT_NE(tracker.find(R"("ended":"relocalised")"), std::string::npos) << tracker;
  const long long lost = jsonInt(tracker, "lost_frames");
  EXPECT_LE(lost, 10) << tracker;
  // One trajectory: every frame of both runs but those lost before the relocalisation.
  EXPECT_EQ(rekon::readTumTrajectory(dir / "export/trajectory.txt").size(), static_cast<size_t>(kFrames - lost));
  const std::string gt = room + "/groundtruth.txt";
  const double both = ateOf(gt, dir / "export/trajectory.txt"), single = ateOf(gt, dir / "single/trajectory.txt");
  EXPECT_GT(single, 0.0);
  EXPECT_LT(both, 1.5 * single) << "ATE " << both << " vs " << single;
  // One map: the session's mesh through the same alignment.
  const double both_corr = corrOf(room, dir / "export"), single_corr = corrOf(room, dir / "single");
  EXPECT_GT(single_corr, 0.0);
  EXPECT_LT(both_corr, 1.5 * single_corr) << "CORR " << both_corr << " vs " << single_corr;
  std::cout << "ATE both " << both << " single " << single << "; CORR both " << both_corr << " single " << single_corr << "\n";
  const std::string mapper = readText(dir / "second/mapper_stats.json");
  EXPECT_GT(jsonInt(mapper, "restored_keyframes"), 10) << mapper;
}

// A session of the room's first 60 frames, refused by `rekon run --continue`
// with one line and left as it was: a dataset of another camera, a newer
// format, a cut tracker keyframe, a missing KF keyframe image, a damaged
// graph, and a scene the session never saw (no frame relocalises within
// session.relocalise_frames; the run stops with the tracker's line).
TEST(SessionContinue, RefusedSessionsAreOneLineAndLeftUntouched) {
  rekon::test::TempDir dir;
  const std::string room = dir / "room", session = dir / "session";
  ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene room --frames 60 --out " + room), 0);
  std::string log;
  ASSERT_EQ(runInNetns("--dataset " + room + " --out " + (dir / "first") + " --session " + session, &log), 0) << log;
  const auto copy = [&](const std::string& name) {
    fs::copy(session, dir / name, fs::copy_options::recursive);
    return dir / name;
  };
  const auto expect_refused = [&](const std::string& s, const std::string& dataset, const std::string& expected,
                                  const std::string& sets = "") {
    SCOPED_TRACE(s);
    const auto before = contents(s);
    std::string out;
    EXPECT_NE(runInNetns("--dataset " + dataset + " --out " + s + "_run --continue " + s + " " + sets, &out), 0) << out;
    EXPECT_NE(out.find(expected), std::string::npos) << out;
    EXPECT_TRUE(contents(s) == before) << "the session changed";
  };

  const std::string other = dir / "other_camera";
  fs::create_directories(other);
  for (const char* f : {"rgb.txt", "depth.txt", "groundtruth.txt"}) fs::copy_file(fs::path(room) / f, fs::path(other) / f);
  for (const char* d : {"rgb", "depth"}) fs::create_directory_symlink(fs::path(room) / d, fs::path(other) / d);
  std::ofstream(other + "/camera.yaml") << "640 480 500 500 319.5 239.5 5000\n";
  expect_refused(session, other, "was made with another camera");

  const std::string newer = copy("newer");
  std::string yaml = readText(newer + "/session.yaml");
  yaml.replace(yaml.find("format_version: 1"), 17, "format_version: 99");
  std::ofstream(newer + "/session.yaml") << yaml;
  expect_refused(newer, room, "newer than this rekon's");

  const std::string cut = copy("cut_dvo");
  fs::resize_file(cut + "/tracker/dvo_000001.rkd", 1000);
  expect_refused(cut, room, "dvo_000001.rkd: cut short");
  const std::string missing = copy("missing_kf");
  fs::remove(missing + "/keyframes/kf_000001.rks");
  expect_refused(missing, room, "kf_000001.rks is missing");
  const std::string graph = copy("bad_graph");
  std::ofstream(graph + "/graph.g2o", std::ios::app) << "EDGE_SE3:QUAT 0 1 nonsense\n";
  expect_refused(graph, room, "graph.g2o:");

  const std::string tabletop = dir / "tabletop";
  ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene tabletop --frames 30 --out " + tabletop), 0);
  expect_refused(copy("unseen"), tabletop, "none of the first 20 frames relocalised", "--set session.relocalise_frames=20");
}

}  // namespace
