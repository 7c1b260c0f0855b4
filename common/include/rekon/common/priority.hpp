#pragma once
// Thread priority (Linux: every thread has a nice value of its own, and a
// thread starts with its creator's).

namespace rekon {

// Sets the calling thread's nice value (0-19; higher yields more), so that
// the threads it starts afterwards share it. False when the system refused
// (the thread keeps its priority; callers log it and go on).
bool setThisThreadsNice(int nice);

}  // namespace rekon
