#pragma once
// What every consumer of graph_update_t needs (the mapper, the tracker's loop
// closure, a viewer): the version filter, and the keyframe poses read with
// validation. Updates carry the complete graph, so an older or repeated one
// (UDP reordering, the final update sent several times) has nothing to add.
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#include "rekon/common/pose.hpp"
#include "rekon_msgs/graph_update_t.hpp"

namespace rekon {

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

// (keyframe id, world pose) of every keyframe in the update: at most
// num_keyframes, never past either array. A rekon::Error naming the update's
// version and the keyframe when a pose is invalid (NaN, non-unit quaternion):
// the whole update is then unusable.
std::vector<std::pair<int64_t, Pose>> graphPoses(const rekon_msgs::graph_update_t& msg);

}  // namespace rekon
