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

}  // namespace rekon
