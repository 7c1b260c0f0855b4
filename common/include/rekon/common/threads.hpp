#pragma once
// Threads a library starts and does not wait for. OpenNI2's DummyDevice: its
// stream's stop() clears a flag, and the thread raises one more frame into
// the stream before it looks, so wait for the threads start() started to end
// before destroying the stream. OpenNI2's file device: its thread sets its
// running flag itself when it first runs, so a close() before that is lost
// and the thread is cancelled 3 s later while the driver is unloaded (a
// segfault at exit); wait for the threads open() started to block first.
#include <chrono>
#include <functional>
#include <set>

namespace rekon {

// Calls `call` and returns the ids of the threads of this process that run
// after it and did not before (from /proc/self/task).
std::set<int> threadsStartedBy(const std::function<void()>& call);

// Waits until each of `ids` has ended or sleeps (state S in /proc: it has run
// up to a blocking call), at most `limit`; false when one has not.
bool waitForThreadsToBlock(const std::set<int>& ids, std::chrono::milliseconds limit);

// Waits until none of `ids` runs any more, at most `limit`; false when one still does.
bool waitForThreadsToEnd(const std::set<int>& ids, std::chrono::milliseconds limit);

}  // namespace rekon
