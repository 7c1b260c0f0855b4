#pragma once
// spdlog set-up shared by every rekon process: "[time] [service] [level] text" on stderr.
#include <string>

namespace rekon {

// `level` is one of trace, debug, info, warn, error; throws rekon::Error otherwise.
void setupLogging(const std::string& service, const std::string& level);

}  // namespace rekon
