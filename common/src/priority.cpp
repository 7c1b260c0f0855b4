#include "rekon/common/priority.hpp"

#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include "rekon/common/error.hpp"

namespace rekon {

bool setThisThreadsNice(int nice) {
  return setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), nice) == 0;
}

void requireNice(int nice, const std::string& key) {
  if (nice < 0 || nice > 19) throw Error(key + " = " + std::to_string(nice) + " is invalid; it must be between 0 and 19");
}

void applyNice(int nice, const std::string& key) {
  if (nice > 0 && !setThisThreadsNice(nice))
    spdlog::warn("{} {}: the system refused; these threads keep their priority", key, nice);
}

}  // namespace rekon
