#pragma once
// Thread priority (Linux: every thread has a nice value of its own, and a
// thread starts with its creator's).
#include <string>

namespace rekon {

// Sets the calling thread's nice value (0-19; higher yields more), so that
// the threads it starts afterwards share it. False when the system refused
// (the thread keeps its priority; callers log it and go on).
bool setThisThreadsNice(int nice);

// A service's nice setting (mapper.nice, optimiser.nice): rekon::Error
// naming `key` unless it is 0-19.
void requireNice(int nice, const std::string& key);
// Applies such a setting to the calling thread and those it starts
// afterwards; 0 leaves the priority alone, a refusal is a warning naming `key`.
void applyNice(int nice, const std::string& key);

}  // namespace rekon
