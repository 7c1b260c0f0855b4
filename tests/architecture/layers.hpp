#pragma once
// The house rule, checked on the includes ("..." and <...>) and the CMake
// links of the source tree:
//   messages <- common <- services <- tools   (tests may use anything)
// A service includes and links only common/, messages/ and its own folder
// (the mapper also links its CUDA backend); common/ uses no service; cuda/
// uses only the mapper's shared kernel headers (and common's error type);
// messages/ uses nothing of rekon.
#include <cstddef>
#include <string>
#include <vector>

namespace rekon::architecture {

struct Violation {
  std::string file;     // relative to the root
  std::string include;  // as written, or the linked target
  std::string owner;    // layer of the included file or linked target ("services/optimiser", "tools", ...)
  std::string target;   // the linking target for a CMake link, "" for an include
  std::string str() const {
    if (!target.empty()) return file + ": " + target + " links " + include + " of " + owner;
    return file + " includes \"" + include + "\" of " + owner;
  }
};

// What a check of a tree looked at, so that a check of nothing shows:
// sources read, includes that named a file of the tree, and links between
// two rekon targets, each under messages/, common/, cuda/ and services/.
struct Scan {
  std::vector<Violation> violations;
  size_t files = 0;
  size_t tree_includes = 0;
  size_t tree_links = 0;
};

// "messages", "common", "cuda", "tools", "tests", "services/<name>", or ""
// for a path (relative to the root) outside every layer.
std::string layerOf(const std::string& relative_path);

// Every include and CMake link under root's messages/, common/, cuda/ and
// services/ that breaks the rule. Includes are resolved against the
// including file's folder first, then against every header of the tree by
// path suffix (so "rekon/optimiser/x.hpp" is owned by the folder whose
// include/ holds it); system and third-party headers resolve to nothing and
// are allowed. A target belongs to the layer of the CMake file that defines it
// (add_library, add_executable, rekon_add_service_node, rekon_add_test); a
// link to anything else (a system library) is allowed.
Scan scan(const std::string& root);
std::vector<Violation> violations(const std::string& root);

// Headers of a service's library API (services/*/include/) that declare a
// command-line entry point (`char** argv`): tools own their commands, a
// service exports a plain C++ API.
std::vector<std::string> headersWithCommandLines(const std::string& root);

}  // namespace rekon::architecture
