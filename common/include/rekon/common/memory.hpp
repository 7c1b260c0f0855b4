#pragma once

#include <cstddef>
#include <string_view>

namespace rekon {

// Makes malloc keep freed memory for reuse instead of handing it back to the
// kernel. Per-frame image buffers (a few MiB each) are otherwise mapped and
// unmapped on every frame, and the page faults of touching them afresh cost
// as much as the work on them: keyframe fusion's add() takes 12 instead of
// 23 ms per 640x480 frame with this (rekon_fusion_benchmark), at the same
// peak RSS, and `rekon run` on 7scenes_loop_1000 plays 36-40 instead of 33
// frames/s. Called once at start by every service (runService), the `rekon`
// command (so `rekon bench` measures the services' allocator) and
// rekon_fusion_benchmark; the other standalone benchmarks keep glibc's
// defaults, as their recorded numbers were measured with them.
void keepFreedMemory();

// Hands the free pages inside the heap back to the kernel (malloc_trim:
// every whole free page, not only those at the heap's top) once more than
// `slack_bytes` of this process's resident anonymous memory is not in use
// (RssAnon against what malloc has handed out); true when it did. For a
// thread that frees large buffers in an order that leaves holes: the
// tracker's DVO keyframes (3.3 MB each) are evicted and read back by
// distance from the camera, and with keepFreedMemory the holes were neither
// reused nor returned (corridor, frame 5 600: 249 MB held for 207 MB in
// use, growing). The pages of a trim fault in again when reused (trimming
// after every loop check doubled the tracker's time per frame), so it runs
// only past the slack, not at every call.
bool releaseFreedMemoryBeyond(size_t slack_bytes);

// A field of this process's /proc/self/status in kB ("VmHWM", "RssAnon",
// ...); -1 when it cannot be read.
long long procStatusKb(std::string_view field);

// This process's resident anonymous memory (RssAnon), in bytes; 0 when it
// cannot be read.
size_t residentAnonymousBytes();

}  // namespace rekon
