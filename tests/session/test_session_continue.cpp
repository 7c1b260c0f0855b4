// `rekon run --continue` (issue 18): the synthetic room's first 300 frames
// with --session, then frames 300-599 continuing it, against one run of all
// 600; and sessions that must be refused (another camera, a newer format,
// damaged files, a scene the session never saw) with one line, the session
// untouched. `rekon run --continue --localise-only` (issue 28): a second pass
// of the room placed in a session's map, the session unchanged byte for byte.
#include <gtest/gtest.h>

#include <cmath>
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
using rekon::test::jsonNumber;
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

// Measured: frame 300 is placed against the first run's last keyframe (12
// frames past it) or, when its search ran out of time, frame 301 is. The
// exported session (both runs, one alignment for all frames) has ATE 0.304
// mm and CORR 0.933 mm; the single run 0.287 and 0.925 mm (1.06x and 1.01x).
// Bounds: 1.5x each, and at most 10 frames lost to relocalisation (1 measured).
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
  const long long lost = jsonInt(tracker, "lost_frames");
  // Frame 300 is placed by itself when its search over the session's 16
  // keyframes fits tracker.lost_relocalise_budget_ms (100 ms; it did on the
  // 2-core VM of 2026-12-04, against keyframe 15), else a later frame goes on
  // with the search: then the frames before it form one lost interval from
  // frame 300 that ended in the relocalisation.
  if (lost > 0) {
    EXPECT_NE(tracker.find(R"("first_frame":300,)"), std::string::npos) << tracker;
    EXPECT_NE(tracker.find(R"("ended":"relocalised")"), std::string::npos) << tracker;
  }
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

// A synthetic room dataset of `frames` frames (its shake, wobble and noise from `seed`) in `out`.
void synthRoom(const std::string& out, int frames, int seed) {
  ASSERT_EQ(runCommand("timeout 240 " + binDir() + "/rekon synth --scene room --frames " + std::to_string(frames) +
                       " --seed " + std::to_string(seed) + " --out " + out), 0);
}

// `data` with frames [first, last) cut out (the player numbers the frames
// left from 0 on): the same images, a gap of (last - first) / 30 s.
std::string cutOut(const std::string& data, int first, int last, const std::string& out) {
  fs::create_directories(out);
  for (const char* list : {"rgb.txt", "depth.txt"}) {
    std::ifstream in(data + "/" + list);
    std::ofstream kept(out + "/" + list);
    int n = 0;
    for (std::string line; std::getline(in, line);) {
      const bool frame = !line.empty() && line[0] != '#';
      if (!frame || n < first || n >= last) kept << line << "\n";
      n += frame;
    }
  }
  for (const char* f : {"groundtruth.txt", "camera.yaml"}) fs::copy_file(fs::path(data) / f, fs::path(out) / f);
  for (const char* d : {"rgb", "depth"}) fs::create_directory_symlink(fs::absolute(fs::path(data) / d), fs::path(out) / d);
  return out;
}

// RMSE (m) of the positions of `estimate` against the ground truth `gt`
// seen from `origin` (the ground-truth pose of the session's first frame,
// which the session's world starts at), with no alignment: how far a
// trajectory is from where it lies in the session's map.
double errorInMap(const rekon::Pose& origin, const std::string& gt, const std::string& estimate) {
  std::map<double, rekon::Pose> truth;
  for (const auto& p : rekon::readTumTrajectory(gt)) truth[p.timestamp] = p.pose;
  double sum = 0;
  size_t n = 0;
  for (const auto& e : rekon::readTumTrajectory(estimate)) {
    const auto it = truth.lower_bound(e.timestamp - 1e-4);
    if (it == truth.end() || it->first > e.timestamp + 1e-4) continue;
    sum += ((origin.inverse() * it->second).translation() - e.pose.translation()).squaredNorm();
    ++n;
  }
  return n ? std::sqrt(sum / static_cast<double>(n)) : -1.0;
}

// The room's first 300 frames scanned into a session (seed 1), then a second
// pass along the same path (seed 2: another shake, another wobble of height,
// yaw and pitch, other sensor noise) from its frame 40, with frames 150-189
// cut out (1.3 s: a gap in the data, after which the tracker relocalises
// again), localised in that session; and the tabletop, which the session
// never saw, never placed.
//
// Measured: the second pass relocalised at its first frame and again right
// after the gap; 220 of 220 frames placed, 10 keyframes placed by the map, 0
// by odometry; ATE 0.256 mm against the scan's 0.265 mm (0.97x); in the
// session's own frame, without alignment, 0.851 mm against the scan's 0.773
// mm (1.10x); 3.6 s for the 220 frames. Bounds: 1.5x the scan's for both (the
// issue's), and at most 10 frames lost (relocalisation has a wall-time budget
// per frame, so the frames it takes follow the machine's load).
TEST(SessionLocalise, ASecondPassIsPlacedInTheSessionsMapAndTheSessionStaysAsItWas) {
  rekon::test::TempDir dir;
  const std::string room = dir / "room", second = dir / "second_pass", session = dir / "session";
  synthRoom(room, kFirstRun, 1);
  synthRoom(second, kFirstRun, 2);
  std::string log;
  ASSERT_EQ(runInNetns("--dataset " + room + " --out " + (dir / "scan") + " --session " + session, &log), 0) << log;
  const auto before = contents(session);
  const std::string cut = cutOut(second, 150, 190, dir / "second_cut");
  ASSERT_EQ(runInNetns("--dataset " + cut + " --out " + (dir / "localised") + " --continue " + session +
                       " --localise-only --set player.first_frame=40", &log), 0) << log;
  EXPECT_TRUE(contents(session) == before) << "the session changed";
  // The tracker alone: nothing that adds to the graph or the map ran.
  EXPECT_TRUE(fs::exists(dir / "localised/tracker.log"));
  EXPECT_FALSE(fs::exists(dir / "localised/optimiser.log"));
  EXPECT_FALSE(fs::exists(dir / "localised/mapper.log"));

  const std::string tracker = readText(dir / "localised/tracker_stats.json");
  EXPECT_GE(jsonInt(tracker, "relocalisations"), 2) << tracker;  // the first frame, and after the gap
  EXPECT_GE(jsonInt(tracker, "keyframes_placed_by_map"), 5) << tracker;
  const long long placed = jsonInt(tracker, "localised_frames"), lost = jsonInt(tracker, "lost_frames");
  EXPECT_EQ(placed + lost, kFirstRun - 40 - 40) << tracker;
  EXPECT_LE(lost, 10) << tracker;
  const std::string stats = readText(dir / "localised/stats.json");
  EXPECT_EQ(jsonInt(stats, "localised_frames"), placed) << stats;
  EXPECT_EQ(rekon::readTumTrajectory(dir / "localised/trajectory.txt").size(), static_cast<size_t>(placed));

  const double scan = ateOf(room + "/groundtruth.txt", dir / "scan/trajectory.txt");
  const double localised = ateOf(second + "/groundtruth.txt", dir / "localised/trajectory.txt");
  EXPECT_GT(scan, 0.0);
  EXPECT_GT(localised, 0.0);
  EXPECT_LT(localised, 1.5 * scan) << "ATE " << localised << " vs the scan's " << scan;
  // In the session's frame, no alignment: the poses are where the map is.
  const rekon::Pose origin = rekon::readTumTrajectory(room + "/groundtruth.txt").front().pose;
  const double scan_in_map = errorInMap(origin, room + "/groundtruth.txt", dir / "scan/trajectory.txt");
  const double in_map = errorInMap(origin, second + "/groundtruth.txt", dir / "localised/trajectory.txt");
  EXPECT_GT(scan_in_map, 0.0);
  EXPECT_LT(in_map, 1.5 * scan_in_map) << "error in the map " << in_map << " vs the scan's " << scan_in_map;
  std::cout << "ATE scan " << scan << " localised " << localised << "; in the map (no alignment) scan " << scan_in_map
            << " localised " << in_map << "; " << placed << " frames placed, " << lost << " lost, "
            << jsonNumber(stats, "wall_seconds") << " s\n";

  // A spill folder that is the session's: the tracker's keyframes would replace the session's own files.
  EXPECT_NE(runInNetns("--dataset " + cut + " --out " + (dir / "spill") + " --continue " + session +
                       " --localise-only --set tracker.keyframe_spill_dir=" + session, &log), 0);
  EXPECT_NE(log.find("tracker.keyframe_spill_dir is the session folder"), std::string::npos) << log;
  EXPECT_TRUE(contents(session) == before) << "the session changed";

  // A scene the session never saw: every frame lost, no pose, the run says so (and ends well: a localiser waits).
  const std::string tabletop = dir / "tabletop";
  ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene tabletop --frames 20 --out " + tabletop), 0);
  ASSERT_EQ(runInNetns("--dataset " + tabletop + " --out " + (dir / "unseen") + " --continue " + session +
                       " --localise-only", &log), 0) << log;
  EXPECT_NE(log.find("no frame was placed in the session's map (20 lost)"), std::string::npos) << log;
  EXPECT_TRUE(rekon::readTumTrajectory(dir / "unseen/trajectory.txt").empty());
  EXPECT_TRUE(contents(session) == before) << "the session changed";
}

// --localise-only needs a session: one line, a failure status, no output folder.
TEST(SessionLocalise, WithoutASessionIsOneLine) {
  rekon::test::TempDir dir;
  const std::string data = dir / "tabletop";
  ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene tabletop --frames 2 --out " + data), 0);
  const auto expect_refused = [&](const std::string& args, const std::string& expected) {
    SCOPED_TRACE(args);
    std::string out;
    EXPECT_NE(runCommand(binDir() + "/rekon run --dataset " + data + " --out " + (dir / "run") + " " + args, &out), 0);
    EXPECT_NE(out.find(expected), std::string::npos) << out;
    EXPECT_EQ(rekon::test::crashLines(out), "") << out;
    EXPECT_FALSE(fs::exists(dir / "run"));
  };
  expect_refused("--localise-only", "--localise-only localises in a saved session: give the session with --continue SESSION");
  expect_refused("--set session.localise_only=true", "session.localise_only localises in a saved session");
  expect_refused("--continue " + (dir / "nowhere") + " --localise-only", "nowhere is not a rekon session (no session.yaml)");
}

}  // namespace
