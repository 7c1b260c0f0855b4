// CsvLog (common/csv_log.hpp): rows reach the file while it is still open
// (a run killed later keeps them), a folder that cannot be written is one
// error naming the file.
#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <thread>

#include "rekon/common/csv_log.hpp"
#include "rekon/common/error.hpp"
#include "test_support.hpp"

namespace rekon {
namespace {

TEST(CsvLog, RowsReachTheFileWithinASecondWhileItIsStillOpen) {
  test::TempDir dir;
  const std::string path = dir / "t.csv";
  CsvLog log(path, "frame_id,ms");
  EXPECT_EQ(test::readText(path), "frame_id,ms\n") << "the header at once";
  log.row(0, 1.5);
  log.row(1, 2.25);
  std::this_thread::sleep_for(std::chrono::milliseconds(1100));
  log.row(2, 3);  // a second after the last flush: everything so far goes to the file
  EXPECT_EQ(test::readText(path), "frame_id,ms\n0,1.5\n1,2.25\n2,3\n");
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
