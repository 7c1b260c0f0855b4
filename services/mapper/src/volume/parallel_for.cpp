#include "parallel_for.hpp"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

namespace rekon::volume {
namespace {

class ThreadPool {
 public:
  ThreadPool() : workers_(std::max(1u, std::thread::hardware_concurrency())) {
    for (int i = 1; i < workers_; ++i) threads_.emplace_back([this, i] { workerLoop(i); });
  }
  ~ThreadPool() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    wake_.notify_all();
    for (auto& t : threads_) t.join();
  }
  int workers() const { return workers_; }

  void run(int n, int grain, int max_workers, const std::function<void(int, int, int)>& body) {
    if (n <= 0) return;
    grain = std::max(1, grain);
    const int wanted = std::min({max_workers > 0 ? max_workers : workers_, workers_, (n + grain - 1) / grain});
    if (wanted <= 1) {
      body(0, n, 0);
      return;
    }
    std::lock_guard<std::mutex> one_job(run_mutex_);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      body_ = &body;
      n_ = n;
      grain_ = grain;
      next_.store(0);
      participants_ = wanted;
      pending_ = wanted - 1;
      ++generation_;
    }
    wake_.notify_all();
    work(0);
    std::exception_ptr error;
    {
      // Every worker is out of `body` before it goes out of scope, even when one of them threw.
      std::unique_lock<std::mutex> lock(mutex_);
      done_.wait(lock, [this] { return pending_ == 0; });
      body_ = nullptr;
      error = std::exchange(error_, nullptr);
    }
    if (error) std::rethrow_exception(error);
  }

 private:
  // A chunk's exception ends the loop: the first is kept for run() to throw on
  // the caller's thread, and the chunks not yet taken are left undone.
  void work(int worker) {
    try {
      while (true) {
        const int begin = next_.fetch_add(grain_);
        if (begin >= n_) break;
        (*body_)(begin, std::min(n_, begin + grain_), worker);
      }
    } catch (...) {
      next_.store(n_);
      std::lock_guard<std::mutex> lock(mutex_);
      if (!error_) error_ = std::current_exception();
    }
  }
  void workerLoop(int worker) {
    uint64_t seen = 0;
    while (true) {
      {
        std::unique_lock<std::mutex> lock(mutex_);
        wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
        if (stop_) return;
        seen = generation_;
        if (worker >= participants_) continue;
      }
      work(worker);
      {
        std::lock_guard<std::mutex> lock(mutex_);
        --pending_;
      }
      done_.notify_one();
    }
  }

  const int workers_;
  std::vector<std::thread> threads_;
  std::mutex run_mutex_, mutex_;
  std::condition_variable wake_, done_;
  const std::function<void(int, int, int)>* body_ = nullptr;
  int n_ = 0, grain_ = 1, participants_ = 0, pending_ = 0;
  std::atomic<int> next_{0};
  std::exception_ptr error_;  // the first exception of the current loop's chunks
  uint64_t generation_ = 0;
  bool stop_ = false;
};

ThreadPool& pool() {
  static ThreadPool instance;
  return instance;
}

}  // namespace

int parallelWorkers() { return pool().workers(); }

void parallelFor(int n, int grain, int max_workers, const std::function<void(int, int, int)>& body) {
  pool().run(n, grain, max_workers, body);
}

}  // namespace rekon::volume
