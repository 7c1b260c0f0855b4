#include "rekon/common/logging.hpp"

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "rekon/common/error.hpp"

namespace rekon {

void setupLogging(const std::string& service, const std::string& level) {
  const auto lvl = spdlog::level::from_str(level);
  if (lvl == spdlog::level::off && level != "off") {
    throw Error("log level '" + level + "' is unknown; use trace, debug, info, warn or error");
  }
  spdlog::drop(service);  // set-up may run twice in one process (rekon demo, then run)
  auto logger = spdlog::stderr_color_mt(service);
  spdlog::set_default_logger(logger);
  spdlog::set_pattern("[%H:%M:%S.%e] [%n] [%^%l%$] %v");
  spdlog::set_level(lvl);
  spdlog::flush_on(spdlog::level::info);
}

}  // namespace rekon
