#pragma once
// rekon's one error type: a single line that names the thing that is wrong and
// how to fix it. Services catch it at the top, log it, and exit non-zero.
#include <stdexcept>
#include <string>

namespace rekon {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what_and_fix) : std::runtime_error(what_and_fix) {}
};

// The exception being handled, as one line: a rekon::Error's own text; any
// other (YAML, OpenCV, filesystem, std::out_of_range, ...) its type and its
// text with line breaks folded. Call it only inside a catch block; every
// binary's top level and every thread body ends with `catch (...)` and this.
std::string currentExceptionLine();

}  // namespace rekon
