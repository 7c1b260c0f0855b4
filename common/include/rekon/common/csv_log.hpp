#pragma once
// A table that grows as a run goes (a source's capture-to-pose latencies, the
// mapper's frame and round times): each row is written as it comes and the
// file is flushed at most once a second and when closed, so a long run that
// is stopped or killed keeps what it measured, and memory does not grow with
// the run's length. A write that fails later (a full disk) is logged once
// and the table's later rows are lost; the run goes on.
#include <chrono>
#include <fstream>
#include <string>

namespace rekon {

class CsvLog {
 public:
  // Creates (truncates) `path` with its header line, or with `append` adds to
  // the rows already there (a restarted service's table goes on; the header
  // only when the file is new or empty); rekon::Error naming the file when it
  // cannot be written.
  CsvLog(const std::string& path, const std::string& header, bool append = false);

  // One row of the values, comma-separated, in the order given.
  template <typename First, typename... Rest>
  void row(const First& first, const Rest&... rest) {
    out_ << first;
    ((out_ << ',' << rest), ...);
    out_ << '\n';
    flushOncePerSecond();
  }

 private:
  void flushOncePerSecond();
  std::string path_;
  std::ofstream out_;
  std::chrono::steady_clock::time_point flushed_;
  bool failed_ = false;
};

}  // namespace rekon
