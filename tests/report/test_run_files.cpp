// Reading the timing and re-integration CSV files that services write.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "rekon/common/error.hpp"
#include "rekon/report/run_files.hpp"
#include "test_support.hpp"

namespace {

using namespace rekon::report;

std::string write(const rekon::test::TempDir& dir, const std::string& name, const std::string& text) {
  std::ofstream(dir / name) << text;
  return dir / name;
}

TEST(RunFiles, RssCsvReadsTheServiceNameAsText) {
  rekon::test::TempDir dir;
  const auto samples = readRssCsv(write(dir, "rss.csv", "seconds,service,rss_mb\n0.5,mapper,120.5\n"));
  ASSERT_EQ(samples.size(), 1u);
  EXPECT_EQ(samples[0].service, "mapper");
  EXPECT_DOUBLE_EQ(samples[0].seconds, 0.5);
  EXPECT_DOUBLE_EQ(samples[0].rss_mb, 120.5);
}

TEST(RunFiles, RssCsvWithAnotherHeaderIsAnErrorNamingTheHeader) {
  rekon::test::TempDir dir;
  try {
    readRssCsv(write(dir, "rss.csv", "time,service,mb\n0.5,mapper,120\n"));
    FAIL() << "a wrong header should be an error";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("seconds,service,rss_mb"), std::string::npos) << e.what();
  }
}

TEST(RunFiles, TimingCsvReadsEveryColumn) {
  rekon::test::TempDir dir;
  const CsvTable t = readCsvTable(write(dir, "tracker_timing.csv", "frame_id,ms,iterations\n0,5.5,14\n# note\n\n1,nan,11\n"),
                                  kTimingColumns);
  ASSERT_EQ(t.columns.size(), 3u);
  ASSERT_EQ(t.rows.size(), 2u);  // the comment and the empty line are skipped
  EXPECT_EQ(t.column("iterations"), 2);
  EXPECT_EQ(t.column("absent"), -1);
  EXPECT_DOUBLE_EQ(t.values(1)[0], 5.5);
  EXPECT_TRUE(std::isnan(t.values(1)[1]));  // "nan" = not measured
}

TEST(RunFiles, WrongHeaderIsAnErrorNamingTheExpectedColumns) {
  rekon::test::TempDir dir;
  try {
    readCsvTable(write(dir, "mapper_timing.csv", "frame,ms\n0,1\n"), kTimingColumns);
    FAIL() << "a header without frame_id was accepted";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("frame_id,ms"), std::string::npos) << e.what();
  }
}

TEST(RunFiles, NonNumberIsAnErrorNamingFileLineAndColumn) {
  rekon::test::TempDir dir;
  try {
    readCsvTable(write(dir, "t.csv", "frame_id,ms\n0,1\n1,fast\n"));
    FAIL() << "a non-numeric field was accepted";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("t.csv:3"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("column ms"), std::string::npos) << e.what();
  }
}

TEST(RunFiles, RowOfTheWrongLengthIsAnError) {
  rekon::test::TempDir dir;
  EXPECT_THROW(readCsvTable(write(dir, "t.csv", "frame_id,ms\n0,1,2\n")), rekon::Error);
}

}  // namespace
