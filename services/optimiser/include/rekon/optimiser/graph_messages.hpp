#pragma once
// The optimiser's side of the bus messages: validated conversions of what
// arrives (each throws rekon::Error naming the message and what is wrong, so
// that the service logs one line and drops it), the graph update it sends,
// and every tracked frame's world pose from the optimised keyframes.
#include <cstdint>
#include <vector>

#include "rekon/common/pose.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::optimiser {

struct KeyframeIn {
  int64_t id = 0;
  Pose pose_world = Pose::Identity();
};

// A tracked frame as the trajectory needs it.
struct TrackedFrame {
  int64_t frame_id = 0;
  double timestamp = 0.0;
  int64_t keyframe_id = 0;
  Pose pose_in_keyframe = Pose::Identity();
  bool lost = false;  // tracking was lost: the pose is the last good one
};

KeyframeIn keyframeFromMsg(const rekon_msgs::keyframe_t& msg);
// Checks the kind and that poses and the information are finite; PoseGraph::addConstraint
// checks the rest (known ids, positive definite information). The information
// is multiplied by `information_scale` (OptimiserServiceParams).
Constraint constraintFromMsg(const rekon_msgs::constraint_t& msg, double information_scale = 1.0);
TrackedFrame trackedFrameFromMsg(const rekon_msgs::tracked_frame_t& msg);

// Every keyframe's pose (complete state), ascending id.
rekon_msgs::graph_update_t graphUpdateMsg(const PoseGraph& graph, int64_t version, bool final_update);

// World pose of every frame = its keyframe's pose x pose_in_keyframe, in
// frame order. Lost frames are left out (their pose is the last good one, not
// where the camera was; stats.json lists the lost intervals), as TUM
// trajectories of other systems leave them out; frames whose keyframe the
// graph does not know are left out and counted in `missing_keyframe`.
Trajectory frameTrajectory(const PoseGraph& graph, std::vector<TrackedFrame> frames, size_t* missing_keyframe);

}  // namespace rekon::optimiser
