// setThisThreadsNice (common/priority.hpp): the calling thread's nice value,
// inherited by the threads it starts afterwards (how the mapper lowers all of
// its mapping threads at once), and not by the threads started before.
#include <gtest/gtest.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <condition_variable>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/common/priority.hpp"

namespace rekon {
namespace {

long threadId() { return static_cast<long>(syscall(SYS_gettid)); }

// Field 19 of /proc/self/task/TID/stat (after the parenthesised name).
int niceOf(long tid) {
  std::ifstream in("/proc/self/task/" + std::to_string(tid) + "/stat");
  std::string line;
  std::getline(in, line);
  std::istringstream rest(line.substr(line.rfind(')') + 2));
  std::string field;
  for (int i = 3; i <= 19; ++i) rest >> field;
  return std::stoi(field);
}

TEST(ThreadNice, ThreadsStartedAfterwardsShareItThoseBeforeDoNot) {
  // Relative to where the test starts (ctest may itself run under nice).
  const int base = niceOf(threadId());
  const int lower = std::min(base + 3, 19);
  std::thread([&] {
    long before = 0;
    bool go = false;
    std::mutex m;
    std::condition_variable cv;
    std::thread earlier([&] {
      before = threadId();
      std::unique_lock<std::mutex> lock(m);
      cv.wait(lock, [&] { return go; });
      EXPECT_EQ(niceOf(before), base) << "a thread started before keeps its nice value";
    });
    EXPECT_TRUE(setThisThreadsNice(lower));  // not ASSERT: `earlier` must still be joined
    EXPECT_EQ(niceOf(threadId()), lower);
    std::thread([&] { EXPECT_EQ(niceOf(threadId()), lower) << "a thread started afterwards shares it"; }).join();
    {
      std::lock_guard<std::mutex> lock(m);
      go = true;
    }
    cv.notify_one();
    earlier.join();
  }).join();
  EXPECT_EQ(niceOf(threadId()), base) << "the test's own thread is untouched";
}

// A service's nice setting: 0-19, else one line naming the key.
TEST(ThreadNice, ASettingOutOfRangeIsAnErrorNamingItsKey) {
  EXPECT_NO_THROW(requireNice(0, "mapper.nice"));
  EXPECT_NO_THROW(requireNice(19, "mapper.nice"));
  for (const int nice : {-1, 20}) {
    try {
      requireNice(nice, "mapper.nice");
      FAIL() << nice << " must be rejected";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("mapper.nice = " + std::to_string(nice)), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace rekon
