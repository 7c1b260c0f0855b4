#include "rekon/common/kill_point.hpp"

#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <string>

namespace rekon {

void killPoint(const char* name) {
  const char* spec = std::getenv("REKON_KILL_AT");  // read each time: a test sets it in the child it kills
  if (spec == nullptr) return;
  const std::string at = spec;
  const size_t hash = at.find('#');
  if (at.compare(0, hash, name) != 0) return;
  const long nth = hash == std::string::npos ? 1 : std::strtol(at.c_str() + hash + 1, nullptr, 10);
  static std::atomic<long> hits{0};  // of the one point named: only it is counted
  if (++hits == nth) kill(getpid(), SIGKILL);
}

}  // namespace rekon
