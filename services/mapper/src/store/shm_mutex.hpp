#pragma once
// A mutex that lives in shared memory and survives its holder's death: a
// POSIX robust, process-shared mutex. A process killed while holding it
// (SIGKILL, a crash) does not leave it locked for good: the next locker gets
// it with ownerDied() set and decides whether what the dead holder was doing
// left anything half-written (the keyframe store keeps its writes ordered so
// that it never does, except inside the segment's allocator).
#include <pthread.h>
#include <sys/types.h>

#include <chrono>
#include <string>

namespace rekon::store {

class ShmMutex {
 public:
  ShmMutex();  // constructed in place, once, by the segment's creator
  ~ShmMutex();
  ShmMutex(const ShmMutex&) = delete;
  ShmMutex& operator=(const ShmMutex&) = delete;

  pid_t holder() const { return holder_; }  // the pid that holds it (0: none)

 private:
  friend class ShmLock;
  pthread_mutex_t mutex_;
  pid_t holder_ = 0;
};

// Holds a ShmMutex for its lifetime. Waits up to `patience` for a live
// holder, then throws rekon::Error naming `what` and the holder's pid.
class ShmLock {
 public:
  ShmLock(ShmMutex& m, const std::string& what, std::chrono::seconds patience);
  ~ShmLock();
  ShmLock(ShmLock&& other) noexcept;
  ShmLock(const ShmLock&) = delete;
  ShmLock& operator=(const ShmLock&) = delete;
  ShmLock& operator=(ShmLock&&) = delete;

  // The previous holder died holding the mutex; `deadPid` was its pid.
  bool ownerDied() const { return owner_died_; }
  pid_t deadPid() const { return dead_pid_; }
  // After a death: what it guards is whole again (else the next locker hears of the death too).
  void markConsistent();

 private:
  ShmMutex* m_;
  bool owner_died_ = false;
  pid_t dead_pid_ = 0;
};

}  // namespace rekon::store
