#pragma once
// A small persistent thread pool for the CPU backend's loops: the calling
// thread works too, chunks are taken from an atomic counter.
#include <functional>

namespace rekon::volume {

// Number of workers the pool runs with (hardware threads, at least 1).
int parallelWorkers();

// Calls body(begin, end, worker) for chunks of [0, n) of at most `grain`
// items, on up to `max_workers` workers (0 = all); worker is in [0, parallelWorkers()).
// An exception in `body` on any worker stops the handing out of chunks and is
// thrown here, on the caller's thread, once every worker has left `body`.
void parallelFor(int n, int grain, int max_workers, const std::function<void(int, int, int)>& body);

}  // namespace rekon::volume
