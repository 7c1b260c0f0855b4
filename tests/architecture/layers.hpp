#pragma once
// The house rule, checked on the includes of the source tree:
//   messages <- common <- services <- tools   (tests may use anything)
// A service includes only common/, messages/ and its own folder; common/
// includes no service; cuda/ includes only the shared kernel headers (and
// common's error type); messages/ includes nothing of rekon.
#include <string>
#include <vector>

namespace rekon::architecture {

struct Violation {
  std::string file;     // relative to the root
  std::string include;  // as written
  std::string owner;    // layer of the included file ("services/optimiser", "tools", ...)
  std::string str() const { return file + " includes \"" + include + "\" of " + owner; }
};

// "messages", "common", "cuda", "tools", "tests", "services/<name>", or ""
// for a path (relative to the root) outside every layer.
std::string layerOf(const std::string& relative_path);

// Every include under root's messages/, common/, cuda/ and services/ that
// breaks the rule. Includes are resolved against the including file's folder
// first, then against every header of the tree by path suffix (so
// "rekon/optimiser/x.hpp" is owned by the folder whose include/ holds it);
// system and third-party headers resolve to nothing and are allowed.
std::vector<Violation> violations(const std::string& root);

// Headers of a service's library API (services/*/include/) that declare a
// command-line entry point (`char** argv`): tools own their commands, a
// service exports a plain C++ API.
std::vector<std::string> headersWithCommandLines(const std::string& root);

}  // namespace rekon::architecture
