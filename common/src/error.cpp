#include "rekon/common/error.hpp"

#include <cxxabi.h>

#include <cstdlib>
#include <exception>
#include <memory>
#include <typeinfo>

namespace rekon {
namespace {

std::string typeName(const std::type_info& type) {
  int status = 0;
  std::unique_ptr<char, void (*)(void*)> name(abi::__cxa_demangle(type.name(), nullptr, nullptr, &status), std::free);
  return status == 0 && name ? name.get() : type.name();
}

// OpenCV's and some YAML messages span lines: one line, single spaces, no trailing blank.
std::string folded(const std::string& text) {
  std::string out;
  for (char c : text) {
    const bool space = c == '\n' || c == '\r' || c == '\t' || c == ' ';
    if (space && (out.empty() || out.back() == ' ')) continue;
    out += space ? ' ' : c;
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

}  // namespace

std::string currentExceptionLine() {
  try {
    throw;
  } catch (const Error& e) {
    return folded(e.what());
  } catch (const std::exception& e) {
    return "unexpected " + typeName(typeid(e)) + ": " + folded(e.what()) +
           " (a bug or an unchecked input: please report it with this line)";
  } catch (...) {
    return "unexpected exception of unknown type (a bug: please report it)";
  }
}

}  // namespace rekon
