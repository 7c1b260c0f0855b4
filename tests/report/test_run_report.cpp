// report.html of a run folder: self-contained, with every input that exists
// and a list of those that do not.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <regex>
#include <sstream>

#include "rekon/common/error.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/report/run_report.hpp"
#include "test_support.hpp"

namespace {

using namespace rekon::report;
namespace fs = std::filesystem;

constexpr int kFrames = 60;
constexpr double kZigZagM = 0.01;  // the estimate's alternating error, all of it left after alignment

std::string readText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

size_t countOf(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + what.size())) ++n;
  return n;
}

bool mentions(const std::vector<std::string>& lines, const std::string& what) {
  for (const auto& l : lines) {
    if (l.find(what) != std::string::npos) return true;
  }
  return false;
}

// A 1 m box on a 2 m floor, outward faces, all vertices one color.
rekon::Mesh boxOnFloor(float shift) {
  rekon::Mesh m;
  const auto quad = [&](Eigen::Vector3f a, Eigen::Vector3f b, Eigen::Vector3f c, Eigen::Vector3f d) {
    const int i = static_cast<int>(m.vertices.size());
    for (const auto& v : {a, b, c, d}) {
      m.vertices.push_back(v + Eigen::Vector3f(shift, 0, 0));
      m.colors.push_back({180, 120, 60});
    }
    m.triangles.emplace_back(i, i + 1, i + 2);
    m.triangles.emplace_back(i, i + 2, i + 3);
  };
  quad({-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0});                        // floor, facing up
  quad({-0.5f, -0.5f, 1}, {0.5f, -0.5f, 1}, {0.5f, 0.5f, 1}, {-0.5f, 0.5f, 1});  // box top
  quad({-0.5f, -0.5f, 0}, {0.5f, -0.5f, 0}, {0.5f, -0.5f, 1}, {-0.5f, -0.5f, 1});  // box front
  return m;
}

// A camera circling the scene at 1.5 m height, looking at its centre (z up).
rekon::Trajectory circle() {
  rekon::Trajectory t;
  for (int i = 0; i < kFrames; ++i) {
    const double a = 2 * std::numbers::pi * i / kFrames;
    const Eigen::Vector3d eye(2.5 * std::cos(a), 2.5 * std::sin(a), 1.5);
    const Eigen::Vector3d z = (Eigen::Vector3d(0, 0, 0.5) - eye).normalized();
    const Eigen::Vector3d x = z.cross(Eigen::Vector3d::UnitZ()).normalized(), y = z.cross(x);
    rekon::StampedPose p;
    p.timestamp = i / 30.0;
    p.pose.linear() << x, y, z;
    p.pose.translation() = eye;
    t.push_back(p);
  }
  return t;
}

struct FakeRun {
  rekon::test::TempDir dir;
  std::string run = dir / "run", dataset = dir / "dataset";

  FakeRun() {
    fs::create_directories(run);
    fs::create_directories(dataset);
    const rekon::Trajectory gt = circle();
    rekon::writeTumTrajectory(gt, dataset + "/groundtruth.txt");
    std::ofstream(run + "/dataset.txt") << dataset << "\n";
    // The estimate in another frame (the first camera's), with an up-down zig-zag
    // that no rigid alignment can remove: ATE RMSE = kZigZagM.
    const rekon::Pose to_first_camera = gt.front().pose.inverse();
    rekon::Trajectory est = gt;
    for (size_t i = 0; i < est.size(); ++i) {
      est[i].pose.translation().z() += (i % 2 ? kZigZagM : -kZigZagM);
      est[i].pose = to_first_camera * est[i].pose;
    }
    rekon::writeTumTrajectory(est, run + "/trajectory.txt");
    rekon::writePly(boxOnFloor(0.0f), run + "/mesh.ply");
    rekon::writePly(boxOnFloor(0.1f), run + "/mesh_uncorrected.ply");
    std::ofstream(run + "/stats.json")
        << R"({"frames": 60, "wall_seconds": 2.5, "realtime_factor": 0.8,)"
        << R"( "tracker": {"keyframes": 17, "ms_per_frame_mean": 5.25, "peak_rss_mb": 74.5},)"
        << R"( "mapper": {"voxel_blocks": 4321, "memory": {"voxel_bytes": 98765}},)"
        << R"( "player": {"frames": 60, "sequence_seconds": 2.0}})";
    std::ofstream tracker(run + "/tracker_timing.csv"), mapper(run + "/mapper_timing.csv");
    tracker << "frame_id,ms\n";
    mapper << "frame_id,ms,integrate_ms\n";
    for (int i = 0; i < kFrames; ++i) {
      tracker << i << "," << 5 + i % 3 << "\n";
      mapper << i << "," << 8 + i % 5 << "," << 6 + i % 5 << "\n";
    }
    std::ofstream(run + "/config.yaml") << "run:\n  services: [player, tracker, mapper]\n";
    std::ofstream(run + "/tracker.log") << "[01:00:00.000] [tracker] [info] started\n"
                                        << "[01:00:01.000] [tracker] [warning] frame 7: few valid depth pixels\n"
                                        << "[01:00:02.000] [tracker] [info] done\n";
    std::ofstream(run + "/mapper_reintegration.csv")
        << "time_s,graph_version,keyframes_reintegrated,ms,blocks_streamed\n0.5,1,3,10.5,0\n1.2,2,5,14.0,12\n1.9,3,4,12.5,3\n";
  }
};

TEST(RunReport, IsSelfContained) {
  FakeRun f;
  const RunReportResult r = writeRunReport(f.run);
  const std::string html = readText(r.html_path);
  EXPECT_EQ(html.find("http://"), std::string::npos);
  EXPECT_EQ(html.find("https://"), std::string::npos);
  EXPECT_EQ(html.find("<link"), std::string::npos);
  EXPECT_EQ(html.find("<script"), std::string::npos);
  EXPECT_EQ(html.find("url("), std::string::npos);
  const size_t sources = countOf(html, "src=\"");
  EXPECT_EQ(countOf(html, "src=\"data:image/"), sources);  // every image is inside the page
  EXPECT_EQ(sources, r.images);
}

TEST(RunReport, ShowsEveryInputAsAnInlineImage) {
  FakeRun f;
  const RunReportResult r = writeRunReport(f.run);
  const std::string html = readText(r.html_path);
  // 2 meshes x 2 views as PNG
  EXPECT_EQ(countOf(html, "src=\"data:image/png;base64,"), 4u);
  // trajectory, timing of both services, mapper's columns, 4 re-integration columns as SVG
  EXPECT_EQ(countOf(html, "src=\"data:image/svg+xml;base64,"), 1u + 1u + 1u + 4u);
  EXPECT_TRUE(fs::exists(f.run + "/report/trajectory.csv"));
  EXPECT_TRUE(fs::exists(f.run + "/report/timing.svg"));
}

TEST(RunReport, ContainsTheStatsValues) {
  FakeRun f;
  const std::string html = readText(writeRunReport(f.run).html_path);
  EXPECT_NE(html.find("<h3>tracker</h3>"), std::string::npos);
  EXPECT_NE(html.find(">keyframes</td><td class=\"num\">17<"), std::string::npos);
  EXPECT_NE(html.find(">5.25<"), std::string::npos);
  EXPECT_NE(html.find(">memory.voxel_bytes</td><td class=\"num\">98765<"), std::string::npos);  // nested objects flattened
  EXPECT_NE(html.find(">realtime_factor</td><td class=\"num\">0.8<"), std::string::npos);
}

TEST(RunReport, MemoryTableComparesKeyframeBytesWithTheInputFrames) {
  FakeRun f;
  // 100 MiB of input frames fused into 11 MiB of keyframes: 11.0 % of the input.
  std::ofstream(f.run + "/stats.json") << R"({"tracker": {"peak_rss_mb": 74.5}, "mapper": {"peak_rss_mb": 512.25,)"
                                       << R"( "input_frame_bytes": 104857600, "keyframe_bytes": 11534336, "voxel_bytes": 52428800}})";
  const std::string html = readText(writeRunReport(f.run).html_path);
  EXPECT_NE(html.find("<td>tracker</td><td class=\"num\">74.5</td>"), std::string::npos);  // peak RSS per service
  EXPECT_NE(html.find("<td>mapper</td><td class=\"num\">512.2</td>"), std::string::npos);  // one decimal
  EXPECT_NE(html.find("<td class=\"num\">11.0</td><td class=\"num\">11.0</td>"), std::string::npos);  // 11 MiB, 11.0 %
  EXPECT_NE(html.find("<td class=\"num\">50.0</td><td class=\"num\">50.0</td>"), std::string::npos);  // voxels: 50 MiB
}

TEST(RunReport, RssOverTimeIsPlottedWhenTheLauncherSampledIt) {
  FakeRun f;
  std::ofstream(f.run + "/rss.csv") << "seconds,service,rss_mb\n0.5,tracker,60\n0.5,mapper,100\n1.0,tracker,61\n1.0,mapper,180\n";
  const RunReportResult r = writeRunReport(f.run);
  EXPECT_FALSE(mentions(r.absent, "rss.csv"));
  const std::string data = readText(f.run + "/report/rss.csv");  // the plot's data: one row per sample
  EXPECT_NE(data.find("mapper,1,180"), std::string::npos) << data;
  EXPECT_NE(data.find("tracker,0.5,60"), std::string::npos) << data;
}

TEST(RunReport, WithoutRssCsvTheRssPlotIsListedAsAbsent) {
  FakeRun f;
  const RunReportResult r = writeRunReport(f.run);
  EXPECT_TRUE(mentions(r.absent, "rss.csv: not in the run folder"));
  EXPECT_FALSE(fs::exists(f.run + "/report/rss.svg"));
}

TEST(RunReport, AteAgainstTheDatasetGroundTruth) {
  FakeRun f;
  const RunReportResult r = writeRunReport(f.run);
  ASSERT_TRUE(r.ate.has_value());
  EXPECT_EQ(r.ate->matched, static_cast<size_t>(kFrames));
  EXPECT_NEAR(r.ate->ate_rmse_m, kZigZagM, 1e-4);  // the frame change is removed by the alignment, the zig-zag is not
  EXPECT_NE(readText(r.html_path).find("ATE RMSE 1.00 cm"), std::string::npos);
}

TEST(RunReport, SummarisesPerFrameTiming) {
  FakeRun f;
  const std::string html = readText(writeRunReport(f.run).html_path);
  // tracker: 5,6,7 repeating over 60 frames: mean 6.00, max 7.00
  EXPECT_NE(html.find("<td>tracker</td><td class=\"num\">60</td><td class=\"num\">6.00</td>"), std::string::npos);
}

TEST(RunReport, TimingPlotMarksTheFramePeriod) {
  FakeRun f;
  writeRunReport(f.run);
  // 60 frames over 2 s: 33.3 ms, drawn from the first to the last frame id.
  const std::string csv = readText(f.run + "/report/timing.csv");
  EXPECT_NE(csv.find("frame period 33.3 ms,0,33.3333333\nframe period 33.3 ms,59,33.3333333\n"), std::string::npos) << csv;
}

TEST(RunReport, ServicesComeFromTheRunConfig) {
  FakeRun f;
  std::ofstream(f.run + "/config.yaml") << "run:\n  services: [player, tracker, optimiser, mapper]\n";
  const RunReportResult r = writeRunReport(f.run);
  // The optimiser ran and wrote no timing: a real absence, explained.
  EXPECT_TRUE(mentions(r.absent, "optimiser_timing.csv: not in the run folder")) << r.absent.size();
  std::ofstream(f.run + "/config.yaml") << "run:\n  services: [player, tracker, mapper]\n";
  EXPECT_FALSE(mentions(writeRunReport(f.run).absent, "optimiser_timing.csv"));  // it did not run
}

// Issue 27: every default run's report opened with a red "Absent inputs:
// player_timing.csv", a file nothing writes. A run with every input has no
// such list; the player has no per-frame timing to miss.
TEST(RunReport, ADefaultRunMissesNothing) {
  FakeRun f;
  // What a default run writes besides FakeRun's files: the launcher's RSS
  // samples, the tracker's odometry, the mapper's memory figures.
  std::ofstream(f.run + "/rss.csv") << "seconds,service,rss_mb\n0.0,mapper,100\n1.0,mapper,120\n";
  fs::copy_file(f.run + "/trajectory.txt", f.run + "/odometry.txt");
  rekon::writePly(boxOnFloor(0.0f), f.dataset + "/mesh_gt.ply");  // a synthetic scene's ground-truth surface
  std::ofstream(f.run + "/stats.json") << R"({"frames": 60, "wall_seconds": 2.5, "player": {"frames": 60, "sequence_seconds": 2.0},)"
                                       << R"( "mapper": {"input_frame_bytes": 1000000, "keyframe_bytes": 200000}})";
  const RunReportResult r = writeRunReport(f.run);
  EXPECT_FALSE(mentions(r.absent, "player_timing.csv"));
  const std::string html = readText(r.html_path);
  EXPECT_EQ(html.find("Absent inputs"), std::string::npos);
  EXPECT_EQ(html.find("player_timing.csv"), std::string::npos);
  EXPECT_EQ(html.find("Not in this report"), std::string::npos) << [&] {
    std::string all;
    for (const auto& a : r.absent) all += a + "\n";
    return all;
  }();
}

// What is missing is explained after the sections, not as a red list before them.
TEST(RunReport, MissingInputsAreExplainedAfterTheSections) {
  FakeRun f;
  fs::remove(f.run + "/mapper_reintegration.csv");
  const std::string html = readText(writeRunReport(f.run).html_path);
  const size_t listed = html.find("mapper_reintegration.csv: not in the run folder");
  ASSERT_NE(listed, std::string::npos);
  EXPECT_GT(listed, html.find("<h2>Stats</h2>"));
  EXPECT_NE(html.find("<h2>Not in this report</h2>"), std::string::npos);
}

// mesh.ply and mesh_uncorrected.ply are explained; with the dataset's
// ground-truth mesh the report gives their CORR and COMPL, each mesh moved
// from the run's world (its first camera) into the ground truth's by the
// first poses: mesh.ply is the ground truth here (0 mm), mesh_uncorrected.ply
// the same box 10 cm aside (a capped error, far from 0).
TEST(RunReport, MeshesAreExplainedAndMeasuredAgainstAGroundTruthMesh) {
  FakeRun f;
  std::string html = readText(writeRunReport(f.run).html_path);
  EXPECT_NE(html.find("<code>mesh_uncorrected.ply</code> is the same keyframes fused once"), std::string::npos);
  EXPECT_EQ(html.find("CORR mean"), std::string::npos);  // no ground-truth mesh: no such table
  // ... and the report says why (the 7-Scenes report said "0 absent inputs").
  EXPECT_NE(html.find("surface errors (CORR/COMPL): " + f.dataset + "/mesh_gt.ply does not exist"), std::string::npos);
  const rekon::Pose to_gt = rekon::readTumTrajectory(f.dataset + "/groundtruth.txt").front().pose *
                            rekon::readTumTrajectory(f.run + "/trajectory.txt").front().pose.inverse();
  rekon::Mesh gt = boxOnFloor(0.0f);
  for (auto& v : gt.vertices) v = to_gt.cast<float>() * v;
  rekon::writePly(gt, f.dataset + "/mesh_gt.ply");
  html = readText(writeRunReport(f.run).html_path);
  EXPECT_NE(html.find("<th>CORR mean [mm]</th>"), std::string::npos);
  EXPECT_NE(html.find("<tr><td>mesh.ply</td><td class=\"num\">0.00</td>"), std::string::npos) << html.substr(html.find("CORR"), 800);
  const std::regex uncorrected(R"(<tr><td>mesh_uncorrected.ply</td><td class="num">([0-9.]+)</td>)");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(html, m, uncorrected));
  EXPECT_GT(std::stod(m[1]), 5.0);  // the box's sides and top 10 cm off: many vertices at the 50 mm cap
}

// A COMPL median at the cap (most of the reference never seen: here a large
// floor 5 m below the scan) is explained, not left as a bare 50 mm.
TEST(RunReport, AComplMedianAtTheCapIsExplained) {
  FakeRun f;
  const rekon::Pose to_gt = rekon::readTumTrajectory(f.dataset + "/groundtruth.txt").front().pose *
                            rekon::readTumTrajectory(f.run + "/trajectory.txt").front().pose.inverse();
  const auto write_gt = [&](bool far_floor) {
    rekon::Mesh gt = boxOnFloor(0.0f);
    const int i = static_cast<int>(gt.vertices.size());
    if (far_floor) {
      for (const Eigen::Vector3f& v : {Eigen::Vector3f(-10, -10, -5), Eigen::Vector3f(10, -10, -5),
                                       Eigen::Vector3f(10, 10, -5), Eigen::Vector3f(-10, 10, -5)}) {
        gt.vertices.push_back(v);
        gt.colors.push_back({100, 100, 100});
      }
      gt.triangles.emplace_back(i, i + 1, i + 2);
      gt.triangles.emplace_back(i, i + 2, i + 3);
    }
    for (auto& v : gt.vertices) v = to_gt.cast<float>() * v;
    rekon::writePly(gt, f.dataset + "/mesh_gt.ply");
  };
  write_gt(true);
  const std::string html = readText(writeRunReport(f.run).html_path);
  EXPECT_NE(html.find("A COMPL median at the cap means"), std::string::npos) << html.substr(html.find("CORR"), 1200);
  // Without the far floor the median is far below the cap: no such note.
  write_gt(false);
  const std::string near = readText(writeRunReport(f.run).html_path);
  EXPECT_EQ(near.find("A COMPL median at the cap means"), std::string::npos) << near.substr(near.find("CORR"), 1200);
}

// The re-integration table sums what each round did, but gives a running
// count (graph_version) its value at the end: the sum of 1, 2, 3 is no count
// of anything (a 1 000-frame run's "total" graph_version read 27 077).
TEST(RunReport, ReintegrationTableGivesRunningCountsTheirLastValue) {
  FakeRun f;
  const std::string html = readText(writeRunReport(f.run).html_path);
  EXPECT_NE(html.find("<tr><td>graph_version</td><td class=\"num\">at the end: 3</td>"), std::string::npos)
      << html.substr(html.find("Re-integration activity"), 1500);
  EXPECT_NE(html.find("<tr><td>keyframes_reintegrated</td><td class=\"num\">12.0</td>"), std::string::npos)
      << html.substr(html.find("Re-integration activity"), 1500);
}

// A run stopped by Ctrl-C says so at the top of its report (stats.json's mark).
TEST(RunReport, AnInterruptedRunIsMarked) {
  FakeRun f;
  EXPECT_EQ(readText(writeRunReport(f.run).html_path).find("This run was"), std::string::npos);
  std::ofstream(f.run + "/stats.json") << R"({"frames": 30, "wall_seconds": 1.5, "interrupted": true})";
  const std::string html = readText(writeRunReport(f.run).html_path);
  const size_t mark = html.find("This run was <b>interrupted</b>");
  ASSERT_NE(mark, std::string::npos);
  EXPECT_LT(mark, html.find("<h2>"));
}

TEST(RunReport, CountsWarningsInTheServiceLogsAndShowsTheConfig) {
  FakeRun f;
  const std::string html = readText(writeRunReport(f.run).html_path);
  // tracker.log: 3 lines, 1 warning, 0 errors
  EXPECT_NE(html.find("<td>tracker</td><td class=\"num\">3</td><td class=\"num\">1</td><td class=\"num\">0</td>"),
            std::string::npos);
  EXPECT_NE(html.find("frame 7: few valid depth pixels"), std::string::npos);
  EXPECT_NE(html.find("services: [player, tracker, mapper]"), std::string::npos);
}

TEST(RunReport, GroundTruthOptionOverridesDatasetTxt) {
  FakeRun f;
  fs::remove(f.run + "/dataset.txt");
  RunReportOptions o;
  o.groundtruth = f.dataset + "/groundtruth.txt";
  EXPECT_TRUE(writeRunReport(f.run, o).ate.has_value());
  EXPECT_FALSE(writeRunReport(f.run).ate.has_value());  // neither: no ground truth
}

TEST(RunReport, AbsentInputsAreListedNotFatal) {
  rekon::test::TempDir empty;
  const RunReportResult r = writeRunReport(empty.path());
  for (const char* name : {"ground truth", "trajectory.txt", "mesh.ply", "mesh_uncorrected.ply", "stats.json",
                           "tracker_timing.csv", "mapper_timing.csv", "mapper_reintegration.csv"}) {
    EXPECT_TRUE(mentions(r.absent, name)) << name << " is not listed as absent";
  }
  EXPECT_EQ(r.images, 0u);
  EXPECT_NE(readText(r.html_path).find("mapper_reintegration.csv: not in the run folder"), std::string::npos);
}

TEST(RunReport, UnreadableInputIsListedAndTheRestShown) {
  FakeRun f;
  std::ofstream(f.run + "/tracker_timing.csv") << "frame_id,ms\n0,fast\n";
  std::ofstream(f.run + "/stats.json") << "{\"frames\": [1, 2";
  const RunReportResult r = writeRunReport(f.run);
  EXPECT_TRUE(mentions(r.absent, "tracker_timing.csv: unreadable"));
  EXPECT_TRUE(mentions(r.absent, "stats.json: unreadable"));
  EXPECT_TRUE(r.ate.has_value());
  // Still every image: the timing plot keeps the mapper's series.
  EXPECT_EQ(r.images, 11u);
  const std::string html = readText(r.html_path);
  EXPECT_EQ(html.find("<td>tracker</td><td class=\"num\">60</td>"), std::string::npos);
  EXPECT_NE(html.find("<td>mapper</td><td class=\"num\">60</td>"), std::string::npos);
}

TEST(RunReport, MissingRunFolderIsAnError) {
  rekon::test::TempDir dir;
  EXPECT_THROW(writeRunReport(dir / "no_such_run"), rekon::Error);
}

TEST(ReportCommand, WritesTheReportOfTheRunFolder) {
  FakeRun f;
  fs::remove(f.run + "/dataset.txt");
  std::string program = "rekon report", run_flag = "--run", gt_flag = "--groundtruth", gt = f.dataset + "/groundtruth.txt";
  char* argv[] = {program.data(), run_flag.data(), f.run.data(), gt_flag.data(), gt.data()};
  EXPECT_EQ(reportCommand(5, argv), 0);
  EXPECT_NE(readText(f.run + "/report.html").find("ATE RMSE 1.00 cm"), std::string::npos);
}

}  // namespace

namespace {

TEST(ReportCommand, BadOptionsAreOneLineErrors) {
  rekon::test::TempDir dir;
  std::string program = "rekon report", run_flag = "--run", view_flag = "--top-view", view = "sideways", run = dir.path();
  char* no_run[] = {program.data()};
  EXPECT_THROW(rekon::report::reportCommand(1, no_run), rekon::Error);
  char* bad_view[] = {program.data(), run_flag.data(), run.data(), view_flag.data(), view.data()};
  EXPECT_THROW(rekon::report::reportCommand(5, bad_view), rekon::Error);
}

}  // namespace
