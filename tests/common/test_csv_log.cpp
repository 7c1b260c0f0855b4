// CsvLog (common/csv_log.hpp): each row reaches the file as it is written
// (a service killed later keeps it), a folder that cannot be written is one
// error naming the file.
#include <gtest/gtest.h>

#include <string>

#include "rekon/common/csv_log.hpp"
#include "rekon/common/error.hpp"
#include "test_support.hpp"

namespace rekon {
namespace {

// Each row at once: the optimiser's timing rows of a killed instance were once
// held for up to a second and lost with it (CI of c1f4193,
// Faults.KilledOptimiserRebuildsItsGraphFromTheTrackerAndTheTrajectoryMatches).
TEST(CsvLog, EachRowReachesTheFileAtOnceWhileItIsStillOpen) {
  test::TempDir dir;
  const std::string path = dir / "t.csv";
  CsvLog log(path, "frame_id,ms");
  EXPECT_EQ(test::readText(path), "frame_id,ms\n") << "the header at once";
  log.row(0, 1.5);
  EXPECT_EQ(test::readText(path), "frame_id,ms\n0,1.5\n");
  log.row(1, 2.25);
  EXPECT_EQ(test::readText(path), "frame_id,ms\n0,1.5\n1,2.25\n");
}

TEST(CsvLog, AFolderThatIsNotThereIsOneErrorNamingTheFile) {
  test::TempDir dir;
  const std::string path = dir / "missing/t.csv";
  try {
    CsvLog log(path, "a,b");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace rekon
