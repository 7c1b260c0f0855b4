#include "rekon/common/graph_update.hpp"

#include <algorithm>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"

namespace rekon {

std::vector<std::pair<int64_t, Pose>> graphPoses(const rekon_msgs::graph_update_t& msg) {
  const size_t n = std::min({static_cast<size_t>(std::max(0, msg.num_keyframes)), msg.keyframe_ids.size(), msg.poses.size()});
  std::vector<std::pair<int64_t, Pose>> poses;
  poses.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    const std::optional<Pose> pose = fromMsg(msg.poses[i]);
    if (!pose)
      throw Error("graph update " + std::to_string(msg.version) + " holds an invalid pose for keyframe " +
                  std::to_string(msg.keyframe_ids[i]) + "; update ignored");
    poses.emplace_back(msg.keyframe_ids[i], *pose);
  }
  return poses;
}

}  // namespace rekon
