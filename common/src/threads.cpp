#include "rekon/common/threads.hpp"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>

namespace rekon {
namespace {

std::set<int> threadIds() {
  std::set<int> ids;
  std::error_code error;
  for (std::filesystem::directory_iterator it("/proc/self/task", error), end; !error && it != end; it.increment(error))
    ids.insert(std::stoi(it->path().filename().string()));
  return ids;
}

// The state letter of thread `id` of this process (R, S, D, ...), or 0 when it has ended.
char threadState(int id) {
  std::ifstream stat("/proc/self/task/" + std::to_string(id) + "/stat");
  std::string line;
  if (!std::getline(stat, line)) return 0;
  const size_t name_end = line.rfind(')');  // the name in parentheses may hold spaces
  return name_end == std::string::npos || name_end + 2 >= line.size() ? 0 : line[name_end + 2];
}

// Polls `done` until it holds or `limit` passes.
bool pollUntil(const std::function<bool()>& done, std::chrono::milliseconds limit) {
  const auto give_up = std::chrono::steady_clock::now() + limit;
  for (;;) {
    if (done()) return true;
    if (std::chrono::steady_clock::now() >= give_up) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

}  // namespace

std::set<int> threadsStartedBy(const std::function<void()>& call) {
  const std::set<int> before = threadIds();
  call();
  const std::set<int> after = threadIds();
  std::set<int> started;
  std::set_difference(after.begin(), after.end(), before.begin(), before.end(),
                      std::inserter(started, started.end()));
  return started;
}

bool waitForThreadsToBlock(const std::set<int>& ids, std::chrono::milliseconds limit) {
  return pollUntil(
      [&] {
        return std::all_of(ids.begin(), ids.end(), [](int id) {
          const char state = threadState(id);
          return state == 0 || state == 'S';
        });
      },
      limit);
}

bool waitForThreadsToEnd(const std::set<int>& ids, std::chrono::milliseconds limit) {
  return pollUntil(
      [&] {
        const std::set<int> now = threadIds();
        return std::none_of(ids.begin(), ids.end(), [&](int id) { return now.count(id) > 0; });
      },
      limit);
}

}  // namespace rekon
