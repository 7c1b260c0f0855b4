#include "rekon/common/csv_log.hpp"

#include <spdlog/spdlog.h>

#include "rekon/common/error.hpp"

namespace rekon {

CsvLog::CsvLog(const std::string& path, const std::string& header)
    : path_(path), out_(path), flushed_(std::chrono::steady_clock::now()) {
  out_ << header << '\n' << std::flush;
  if (!out_) throw Error("cannot write " + path + "; check that the output folder exists and is writable");
}

void CsvLog::flushOncePerSecond() {
  const auto now = std::chrono::steady_clock::now();
  if (now - flushed_ < std::chrono::seconds(1) || failed_) return;
  out_.flush();
  flushed_ = now;
  // A table is not worth the run: one line, and the rows after it are lost.
  if (!out_) {
    failed_ = true;
    spdlog::error("cannot write {} (disk full?); its rows from here on are lost: free space in the output folder",
                  path_);
  }
}

}  // namespace rekon
