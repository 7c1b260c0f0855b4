#pragma once
// What every consumer of graph_update_t does first: accept an update only
// when its version is newer than the newest seen. Updates carry the complete
// graph, so an older or repeated one (UDP reordering, the final update sent
// several times) has nothing to add.
#include <cstdint>
#include <limits>

namespace rekon::optimiser {

class GraphUpdateFilter {
 public:
  // True (and remembered) when `version` is newer than every version seen.
  bool accept(int64_t version) {
    if (version <= newest_) return false;
    newest_ = version;
    return true;
  }
  // The newest accepted version; lowest int64 before the first.
  int64_t newest() const { return newest_; }
  bool seenAny() const { return newest_ != std::numeric_limits<int64_t>::min(); }

 private:
  int64_t newest_ = std::numeric_limits<int64_t>::min();
};

}  // namespace rekon::optimiser
