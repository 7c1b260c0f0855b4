// threadsStartedBy, waitForThreadsToBlock and waitForThreadsToEnd
// (common/threads.hpp): how rekon waits for threads OpenNI2's drivers start
// and do not wait for, tried here on threads of the test's own.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>

#include "rekon/common/threads.hpp"

namespace rekon {
namespace {

using std::chrono::milliseconds;

TEST(Threads, AThreadThatSleepsIsFoundStartedAndBlockedAndThenEnded) {
  std::mutex mutex;
  std::condition_variable wake;
  bool go = false;
  std::thread sleeper;
  const std::set<int> started = threadsStartedBy([&] {
    sleeper = std::thread([&] {
      std::unique_lock<std::mutex> lock(mutex);
      wake.wait(lock, [&] { return go; });
    });
  });
  EXPECT_EQ(started.size(), 1u);
  EXPECT_TRUE(waitForThreadsToBlock(started, milliseconds(5000)));
  EXPECT_FALSE(waitForThreadsToEnd(started, milliseconds(50)));  // it still waits
  {
    std::lock_guard<std::mutex> lock(mutex);
    go = true;
  }
  wake.notify_one();
  sleeper.join();
  EXPECT_TRUE(waitForThreadsToEnd(started, milliseconds(5000)));
}

TEST(Threads, AThreadThatNeverBlocksIsNotTakenForBlocked) {
  std::atomic<bool> stop{false};
  std::thread spinner;
  const std::set<int> started = threadsStartedBy([&] {
    spinner = std::thread([&] {
      while (!stop) {
      }
    });
  });
  ASSERT_EQ(started.size(), 1u);
  EXPECT_FALSE(waitForThreadsToBlock(started, milliseconds(100)));
  stop = true;
  spinner.join();
  EXPECT_TRUE(waitForThreadsToBlock(started, milliseconds(100)));  // ended counts
  EXPECT_TRUE(threadsStartedBy([] {}).empty());
}

}  // namespace
}  // namespace rekon
