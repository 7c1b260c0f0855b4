#pragma once
// CPU time in milliseconds, for benchmarks and per-frame statistics: on a
// shared machine other processes inflate wall time but not these.
#include <ctime>

namespace rekon {

namespace detail {
inline double clockMs(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}
}  // namespace detail

// CPU time of the calling thread.
inline double threadCpuMs() { return detail::clockMs(CLOCK_THREAD_CPUTIME_ID); }
// CPU time of all threads of this process (user and system).
inline double processCpuMs() { return detail::clockMs(CLOCK_PROCESS_CPUTIME_ID); }

}  // namespace rekon
