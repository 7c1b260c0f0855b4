#include "rekon/common/memory.hpp"

#include <malloc.h>

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

}  // namespace rekon
