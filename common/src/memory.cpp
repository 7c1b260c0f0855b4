#include "rekon/common/memory.hpp"

#include <malloc.h>

#include <fstream>
#include <limits>
#include <string>

namespace rekon {

void keepFreedMemory() {
  // One arena for all threads: a thread's own arena lives in 64 MiB heaps
  // that are unmapped whenever they fall empty (the mapper's worker frees a
  // KF keyframe's 20 inputs, 66 MiB, at every keyframe), whatever the trim
  // threshold says. Allocations below 64 MiB come from that heap (a fixed
  // threshold also stops glibc from adapting it), trimmed only past 1 GiB.
  mallopt(M_ARENA_MAX, 1);
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
}

long long procStatusKb(std::string_view field) {
  std::ifstream status("/proc/self/status");
  std::string key;
  long long kb = -1;
  while (status >> key) {
    if (key.size() == field.size() + 1 && key.back() == ':' && key.compare(0, field.size(), field) == 0) {
      status >> kb;
      return kb;
    }
    status.ignore(std::numeric_limits<std::streamsize>::max(), '\n');
  }
  return -1;
}

size_t residentAnonymousBytes() {
  const long long kb = procStatusKb("RssAnon");
  return kb < 0 ? 0 : static_cast<size_t>(kb) * 1024;
}

bool releaseFreedMemoryBeyond(size_t slack_bytes) {
  const struct mallinfo2 info = mallinfo2();
  const size_t in_use = info.uordblks + info.hblkhd;
  const size_t resident = residentAnonymousBytes();
  if (resident <= in_use + slack_bytes) return false;
  malloc_trim(0);
  return true;
}

}  // namespace rekon
