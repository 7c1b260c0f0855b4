// rekon bench longrun: the per-minute table, the plots and the goal lines are
// computed from what the run folder holds; a short slice of the building
// through the real services writes all of them.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <regex>

#include "rekon/common/pose.hpp"
#include "rekon/longrun/longrun.hpp"
#include "test_support.hpp"

namespace {

using rekon::test::binDir;
using rekon::test::readText;
using rekon::test::runCommand;
using rekon::test::TempDir;

// A 4-bucket run (10 s buckets, 30 frames/s): every frame posed and fused
// except `unfused` per bucket; capture-to-pose `latency_ms(bucket)`; the
// mapper's RSS `mapper_mb(bucket)`.
template <class Latency, class Rss>
void writeRun(const TempDir& dir, int unfused, Latency latency_ms, Rss mapper_mb) {
  std::ofstream lat(dir / "player_latency.csv"), fused(dir / "mapper_timing.csv"), counts(dir / "source_counts.csv"),
      rss(dir / "longrun_rss.csv"), opt(dir / "optimiser_timing.csv"), rounds(dir / "mapper_reintegration.csv"),
      checks(dir / "tracker_loop_checks.csv");
  lat << "frame_id,captured_s,latency_ms\n";
  fused << "frame_id,ms,fuse_ms,integrate_ms\n";
  counts << "seconds,frames_due,sent,dropped,skipped_late,render_ms_mean\n";
  rss << "seconds,service,rss_mb\n";
  opt << "frame_id,ms,keyframes,graph_version\n";
  rounds << "time_s,graph_version,keyframes_reintegrated,ms,blocks_streamed,final_pass,frames_fused,piece\n";
  checks << "keyframe_id,frame_id,candidates,accepted,ms\n";
  for (int b = 0; b < 4; ++b) {
    for (int i = 0; i < 300; ++i) {
      const int id = b * 300 + i;
      lat << id << ',' << id / 30.0 << ',' << latency_ms(b) << '\n';
      if (i >= unfused) fused << id << ",5,1,4\n";
    }
    counts << 10 * b + 9.5 << ',' << 300 * (b + 1) << ',' << 300 * (b + 1) << ",0,0,20\n";
    rss << 10 * b + 5 << ",mapper," << mapper_mb(b) << '\n';
    opt << b * 300 + 150 << ",2,10," << b << '\n';
    rounds << 10 * b + 5 << ',' << b << ",3,40,0,0,100,0\n";
    checks << 2 * b << ',' << b * 300 + 20 << ",5,2," << 100 + 100 * (b == 3) << '\n';  // the last bucket's twice the others'
  }
  opt << "1199,50,40,4\n";  // the final optimisation: not a live solve
}

std::string line(const std::vector<rekon::longrun::GoalLine>& lines, const std::string& start) {
  for (const auto& l : lines)
    if (l.goal.rfind(start, 0) == 0) return l.verdict + " " + l.measured;
  return "missing: " + start;
}

TEST(LongrunTable, BucketsHoldWhatTheTablesSay) {
  TempDir dir;
  writeRun(dir, 30, [](int b) { return 10.0 + b; }, [](int) { return 100.0; });
  const auto buckets = rekon::longrun::readBuckets(dir.path(), 10.0, 30.0);
  ASSERT_EQ(buckets.size(), 4u);
  EXPECT_EQ(buckets[2].frames_posed, 300);
  EXPECT_EQ(buckets[2].frames_fused, 270);  // 30 left unfused per bucket
  EXPECT_EQ(buckets[2].frames_due, 300);
  EXPECT_DOUBLE_EQ(buckets[3].latency_p95_ms, 13.0);
  EXPECT_DOUBLE_EQ(buckets[1].solve_ms_mean, 2.0);
  EXPECT_DOUBLE_EQ(buckets[3].solve_ms_mean, 2.0);  // the final optimisation (50 ms) is left out
  EXPECT_DOUBLE_EQ(buckets[0].round_ms_mean, 40.0);
  EXPECT_DOUBLE_EQ(buckets[2].loop_check_ms_mean, 100.0);
  EXPECT_DOUBLE_EQ(buckets[0].rss_mb.at("mapper"), 100.0);
}

TEST(LongrunGoals, FusedFramesBelow95PercentFail) {
  TempDir dir;
  writeRun(dir, 30, [](int) { return 10.0; }, [](int) { return 100.0; });  // 90 % fused
  const auto lines = rekon::longrun::judgeGoals(rekon::longrun::readBuckets(dir.path(), 10.0, 30.0), 10.0, 20.0);
  EXPECT_EQ(line(lines, "at least 95 % of frames fused").substr(0, 9), "FAIL 90.0");
  TempDir good;
  writeRun(good, 3, [](int) { return 10.0; }, [](int) { return 100.0; });  // 99 %
  const auto ok = rekon::longrun::judgeGoals(rekon::longrun::readBuckets(good.path(), 10.0, 30.0), 10.0, 20.0);
  EXPECT_EQ(line(ok, "at least 95 % of frames fused").substr(0, 9), "PASS 99.0");
}

TEST(LongrunGoals, LatencyAndMemoryThatGrowFail) {
  TempDir dir;
  // p95 of the last bucket twice the first's; the mapper's RSS 1.5x from the second bucket to the last.
  writeRun(dir, 0, [](int b) { return b == 3 ? 20.0 : 10.0; }, [](int b) { return b == 3 ? 150.0 : 100.0; });
  const auto lines = rekon::longrun::judgeGoals(rekon::longrun::readBuckets(dir.path(), 10.0, 30.0), 10.0, 20.0);
  EXPECT_EQ(line(lines, "capture-to-pose p95").substr(0, 4), "FAIL");
  EXPECT_EQ(line(lines, "RSS of mapper").substr(0, 4), "FAIL");
  EXPECT_EQ(line(lines, "optimiser solve time").substr(0, 4), "PASS");
  EXPECT_EQ(line(lines, "correction round time").substr(0, 4), "PASS");
  EXPECT_EQ(line(lines, "loop-check time per keyframe").substr(0, 10), "FAIL 200 /");
  EXPECT_EQ(line(lines, "end of run"), "PASS 20.0 s");
  EXPECT_EQ(line(lines, "all services together").substr(0, 4), "PASS");
}

TEST(LongrunPlots, EachSeriesHasAPointPerBucket) {
  TempDir dir;
  writeRun(dir, 0, [](int) { return 10.0; }, [](int) { return 100.0; });
  const auto files = rekon::longrun::writePlots(rekon::longrun::readBuckets(dir.path(), 10.0, 30.0), dir.path());
  ASSERT_EQ(files.size(), 4u);
  const std::string svg = readText(dir / "longrun_latency.svg");
  const std::regex p95("data-name=\"p95\"[^>]*points=\"([^\"]*)\"");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(svg, m, p95)) << svg;
  const std::string pts = m[1];
  EXPECT_EQ(std::count(pts.begin(), pts.end(), ','), 4);  // four buckets, four x,y points
}

// The end of run after the last frame: a bucket with memory but no frames.
// The frame counts and latencies stop with the play (they drew a fall to 0
// there), the memory goes on; ticks are plain numbers (2 200, not 2.2e+03).
TEST(LongrunPlots, FramesAndLatencyEndWithThePlayMemoryWithTheRun) {
  TempDir dir;
  writeRun(dir, 0, [](int) { return 10.0; }, [](int) { return 2000.0; });
  std::ofstream(dir / "longrun_rss.csv", std::ios::app) << "45,mapper,1900\n";
  const auto buckets = rekon::longrun::readBuckets(dir.path(), 10.0, 30.0);
  ASSERT_EQ(buckets.size(), 5u);
  rekon::longrun::writePlots(buckets, dir.path());
  const auto points = [](const std::string& svg, const std::string& name) {
    std::smatch m;
    const std::regex series("data-name=\"" + name + "\"[^>]*points=\"([^\"]*)\"");
    if (!std::regex_search(svg, m, series)) return -1;
    const std::string pts = m[1];
    return static_cast<int>(std::count(pts.begin(), pts.end(), ','));
  };
  EXPECT_EQ(points(readText(dir / "longrun_latency.svg"), "p95"), 4);
  EXPECT_EQ(points(readText(dir / "longrun_frames.svg"), "fused"), 4);
  const std::string memory = readText(dir / "longrun_memory.svg");
  EXPECT_EQ(points(memory, "mapper"), 5);
  EXPECT_EQ(memory.find("e+0"), std::string::npos) << memory;
}

TEST(LongrunBench, ATenSecondSliceOfTheBuildingWritesItsTablesPlotsAndSummary) {
  TempDir dir;
  std::string out;
  const std::string cmd = rekon::test::inNetns() + " timeout 200 " + binDir() + "/rekon bench longrun --out " + (dir / "run") +
                          " --frames 300 --bucket-s 2 2>&1";
  ASSERT_EQ(runCommand(cmd, &out), 0) << out;
  for (const char* f : {"longrun.csv", "summary.txt", "longrun_frames.svg", "longrun_latency.svg", "longrun_times.svg",
                        "longrun_memory.svg", "longrun_rss.csv", "mesh.ply", "trajectory.txt", "tracker_loop_checks.csv"})
    EXPECT_TRUE(std::filesystem::exists(std::filesystem::path(dir / "run") / f)) << f;
  // The fused line counts mapper_timing.csv's rows against the frames the source had due.
  int fused = -1;
  {
    std::ifstream t(dir / "run/mapper_timing.csv");
    for (std::string l; std::getline(t, l);) ++fused;
  }
  const std::string summary = readText(dir / "run/summary.txt");
  const std::string counted = fmt::format("({} of 300;", fused);
  EXPECT_NE(summary.find(counted), std::string::npos) << summary;
  EXPECT_NE(summary.find("end of run (final pass and meshes) within 180 s:"), std::string::npos) << summary;
  EXPECT_TRUE(rekon::test::leftoverSegments(dir / "run").empty());
  // The run scores itself against the truth its source wrote: the walk's 300 poses.
  EXPECT_EQ(rekon::readTumTrajectory(dir / "run/groundtruth.txt").size(), 300u);
  EXPECT_TRUE(std::filesystem::exists(dir / "run/mesh_gt.ply"));
  const double ate = rekon::test::ateOf(dir / "run/groundtruth.txt", dir / "run/trajectory.txt");
  ASSERT_GE(ate, 0.0) << "rekon eval traj failed";
  EXPECT_LT(ate, 0.001);  // measured 0.091 mm: a bound of 11x
}

}  // namespace
