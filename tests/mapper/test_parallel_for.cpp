// The CPU backend's thread pool (services/mapper/src/volume/parallel_for.hpp):
// an exception in the loop body, on a pool thread or on the caller's, reaches
// the caller of parallelFor() once no worker is in the body any more, and the
// pool goes on. Before, a pool thread's exception was std::terminate, and the
// caller's left the workers running a body that had gone out of scope.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <stdexcept>
#include <thread>

#include "parallel_for.hpp"

namespace rekon::volume {
namespace {

constexpr int kItems = 200;

// Every chunk on a pool thread throws; the caller's first chunk waits (up to
// 10 s) until a pool thread has taken one, so that one surely does.
TEST(ParallelFor, APoolThreadsExceptionReachesTheCaller) {
  if (parallelWorkers() < 2) GTEST_SKIP() << "one hardware thread: no pool threads";
  std::atomic<bool> pool_thread_ran{false};
  const std::function<void(int, int, int)> body = [&](int, int, int worker) {
    if (worker != 0) {
      pool_thread_ran = true;
      throw std::runtime_error("a pool thread's chunk failed");
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (!pool_thread_ran && std::chrono::steady_clock::now() < deadline) std::this_thread::yield();
  };
  EXPECT_THROW(parallelFor(kItems, 1, 0, body), std::runtime_error);
  EXPECT_TRUE(pool_thread_ran);
}

// The caller's first chunk throws while pool threads are busy: parallelFor
// returns only after they left the body (no call after it returned).
TEST(ParallelFor, TheCallersExceptionWaitsForEveryWorkerToLeaveTheBody) {
  if (parallelWorkers() < 2) GTEST_SKIP() << "one hardware thread: no pool threads";
  std::atomic<bool> returned{false};
  std::atomic<int> calls_after_return{0};
  const std::function<void(int, int, int)> body = [&](int, int, int worker) {
    if (worker == 0) throw std::runtime_error("the caller's chunk failed");
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    if (returned) ++calls_after_return;
  };
  EXPECT_THROW(parallelFor(kItems, 1, 0, body), std::runtime_error);
  returned = true;
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // the old pool went on with about kItems ms of chunks
  EXPECT_EQ(calls_after_return.load(), 0);
}

TEST(ParallelFor, ThePoolGoesOnAfterAFailedLoop) {
  const std::function<void(int, int, int)> failing = [](int, int, int) { throw std::runtime_error("failed"); };
  EXPECT_THROW(parallelFor(kItems, 1, 0, failing), std::runtime_error);
  std::atomic<int> sum{0};
  parallelFor(kItems, 7, 0, [&](int begin, int end, int) {
    for (int i = begin; i < end; ++i) sum += i;
  });
  EXPECT_EQ(sum.load(), kItems * (kItems - 1) / 2) << "every item once";
}

}  // namespace
}  // namespace rekon::volume
