#pragma once
// A table that grows as a run goes (a source's capture-to-pose latencies, the
// mapper's frame and round times): each row reaches the file as it comes, so
// a run that is stopped or killed (kill -9 included) keeps every row it
// measured, and memory does not grow with the run's length. A write that fails later (a full disk) is logged once
// and the table's later rows are lost; the run goes on.
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

  // One row of the values, comma-separated, in the order given. It reaches the
  // file at once: a service killed (kill -9) right after keeps every row it
  // wrote (a row is one write; a few per second at most in every table).
  template <typename First, typename... Rest>
  void row(const First& first, const Rest&... rest) {
    out_ << first;
    ((out_ << ',' << rest), ...);
    out_ << '\n';
    flushRow();
  }

 private:
  void flushRow();
  std::string path_;
  std::ofstream out_;
  bool failed_ = false;
};

}  // namespace rekon
