#pragma once
// The optimiser's side of the bus messages: validated conversions of what
// arrives (each throws rekon::Error naming the message and what is wrong, so
// that the service logs one line and drops it), the graph update it sends,
// and every tracked frame's world pose from the optimised keyframes.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "rekon/common/pose.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/external_constraint_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::optimiser {

// The channel of external_constraint_t, from any process (`rekon constrain`);
// only the optimiser listens (after the prefix, as the names in bus.hpp).
inline constexpr const char* kExternalConstraintsChannel = "EXTERNAL_CONSTRAINTS";
// The optimiser sends each external_constraint_t it took in (a repeat too)
// back on this channel: a sender resends until it sees its own come back.
inline constexpr const char* kExternalConstraintsAckChannel = "EXTERNAL_CONSTRAINTS_ACK";

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

// A constraint from outside the frontend (messages/external_constraint.lcm):
// a loop edge (`relative` is to_id in from_id) or an absolute prior
// (`relative` is to_id's world pose; from_id unused). `name` says who sent
// what, for every line about it.
struct ExternalConstraint {
  enum class Kind { Loop, Prior };
  Kind kind = Kind::Loop;
  std::string source;
  int64_t sequence = 0;
  int64_t from_id = 0;
  int64_t to_id = 0;
  Pose pose = Pose::Identity();
  Matrix6d information = Matrix6d::Identity();
  std::string name;
};

KeyframeIn keyframeFromMsg(const rekon_msgs::keyframe_t& msg);
// Checks the kind and that poses and the information are finite; PoseGraph::addConstraint
// checks the rest (known ids, positive definite information). The information
// is multiplied by `information_scale` (OptimiserServiceParams).
Constraint constraintFromMsg(const rekon_msgs::constraint_t& msg, double information_scale = 1.0);
TrackedFrame trackedFrameFromMsg(const rekon_msgs::tracked_frame_t& msg);
// Checks the kind, the ids, that the pose and information are finite;
// PoseGraph::addConstraint checks the information further.
ExternalConstraint externalConstraintFromMsg(const rekon_msgs::external_constraint_t& msg);
// The pose-graph edge that enforces it: a loop edge as it is; a prior as an
// edge from the fixed first keyframe (`anchor`, at `anchor_pose`), which is
// an absolute constraint in the map's world. Both loop kind: robust loss and
// outlier test. Added with e.name as its origin (PoseGraph::addConstraint).
Constraint edgeOf(const ExternalConstraint& e, int64_t anchor, const Pose& anchor_pose);

// Every keyframe's pose (complete state), ascending id.
rekon_msgs::graph_update_t graphUpdateMsg(const PoseGraph& graph, int64_t version, bool final_update);

// World pose of every frame = its keyframe's pose x pose_in_keyframe, in
// frame order. Lost frames are left out (their pose is the last good one, not
// where the camera was; stats.json lists the lost intervals), as TUM
// trajectories of other systems leave them out; frames whose keyframe the
// graph does not know are left out and counted in `missing_keyframe`.
Trajectory frameTrajectory(const PoseGraph& graph, std::vector<TrackedFrame> frames, size_t* missing_keyframe);
// The same from (keyframe id, world pose) pairs in ascending id, as
// graphPoses() reads them from an update and PoseGraph::poses() gives them.
Trajectory frameTrajectory(const std::vector<std::pair<int64_t, Pose>>& keyframe_poses, std::vector<TrackedFrame> frames,
                           size_t* missing_keyframe);

}  // namespace rekon::optimiser
