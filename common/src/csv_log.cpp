#include "rekon/common/csv_log.hpp"

#include <spdlog/spdlog.h>

#include <filesystem>

#include "rekon/common/error.hpp"

namespace rekon {

CsvLog::CsvLog(const std::string& path, const std::string& header, bool append)
    : path_(path) {
  std::error_code ec;
  const bool has_rows = append && std::filesystem::file_size(path, ec) > 0 && !ec;
  out_.open(path, append ? std::ios::app : std::ios::trunc);
  if (!has_rows) out_ << header << '\n';
  out_ << std::flush;
  if (!out_) throw Error("cannot write " + path + "; check that the output folder exists and is writable");
}

void CsvLog::flushRow() {
  if (failed_) return;
  out_.flush();
  // A table is not worth the run: one line, and the rows after it are lost.
  if (!out_) {
    failed_ = true;
    spdlog::error("cannot write {} (disk full?); its rows from here on are lost: free space in the output folder",
                  path_);
  }
}

}  // namespace rekon
