#pragma once

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

}  // namespace rekon
