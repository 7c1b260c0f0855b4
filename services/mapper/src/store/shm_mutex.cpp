#include "shm_mutex.hpp"

#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <ctime>

#include "rekon/common/error.hpp"
#include "rekon/mapper/store/broken_store.hpp"

namespace rekon::store {
namespace {

void check(int rc, const char* call) {
  if (rc != 0) throw Error(std::string("shared-memory mutex: ") + call + " failed (" + std::strerror(rc) + ")");
}

timespec deadlineAfter(std::chrono::seconds patience) {
  timespec now{};
  clock_gettime(CLOCK_REALTIME, &now);  // pthread_mutex_timedlock's clock
  now.tv_sec += patience.count();
  return now;
}

}  // namespace

ShmMutex::ShmMutex() {
  pthread_mutexattr_t attr;
  check(pthread_mutexattr_init(&attr), "pthread_mutexattr_init");
  check(pthread_mutexattr_setpshared(&attr, PTHREAD_PROCESS_SHARED), "pthread_mutexattr_setpshared");
  check(pthread_mutexattr_setrobust(&attr, PTHREAD_MUTEX_ROBUST), "pthread_mutexattr_setrobust");
  const int rc = pthread_mutex_init(&mutex_, &attr);
  pthread_mutexattr_destroy(&attr);
  check(rc, "pthread_mutex_init");
}

// The segment outlives every process; nothing destroys the mutex but the
// segment's removal, and pthread_mutex_destroy on a mutex other processes
// may still use would be wrong.
ShmMutex::~ShmMutex() = default;

ShmLock::ShmLock(ShmMutex& m, const std::string& what, std::chrono::seconds patience) : m_(&m) {
  const pid_t before = m.holder_;  // a hint for the messages; the mutex decides
  const timespec deadline = deadlineAfter(patience);
  const int rc = pthread_mutex_timedlock(&m.mutex_, &deadline);
  if (rc == EOWNERDEAD) {
    owner_died_ = true;
    dead_pid_ = m.holder_;
  } else if (rc == ETIMEDOUT) {
    throw Error(what + " has been locked by process " + std::to_string(before) + " for " +
                std::to_string(patience.count()) + " s; stop that process, or remove it (rekon keyframes --remove)");
  } else if (rc == ENOTRECOVERABLE) {
    throw BrokenStore(what + " is broken: a process died while changing it; remove it (rekon keyframes --remove) and start without mapper.resume");
  } else {
    check(rc, "pthread_mutex_timedlock");
  }
  m.holder_ = getpid();
}

ShmLock::ShmLock(ShmLock&& other) noexcept
    : m_(other.m_), owner_died_(other.owner_died_), dead_pid_(other.dead_pid_) {
  other.m_ = nullptr;
}

void ShmLock::markConsistent() {
  if (owner_died_) check(pthread_mutex_consistent(&m_->mutex_), "pthread_mutex_consistent");
  owner_died_ = false;
}

// Unlocking after a death without markConsistent() leaves the mutex
// ENOTRECOVERABLE: every later locker hears that the store is broken.
ShmLock::~ShmLock() {
  if (m_ == nullptr) return;
  m_->holder_ = 0;
  pthread_mutex_unlock(&m_->mutex_);
}

}  // namespace rekon::store
