#include "rekon/optimiser/graph_messages.hpp"

#include <algorithm>
#include <cmath>

#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"

namespace rekon::optimiser {

KeyframeIn keyframeFromMsg(const rekon_msgs::keyframe_t& msg) {
  const std::optional<Pose> pose = fromMsg(msg.pose_world);
  if (!pose) throw Error("keyframe " + std::to_string(msg.keyframe_id) + " has a non-finite or non-unit pose; dropped");
  return {msg.keyframe_id, *pose};
}

Constraint constraintFromMsg(const rekon_msgs::constraint_t& msg, double information_scale) {
  const std::string name = "constraint " + std::to_string(msg.from_id) + " -> " + std::to_string(msg.to_id);
  Constraint c;
  if (msg.kind == rekon_msgs::constraint_t::KIND_ODOMETRY) c.kind = EdgeKind::Odometry;
  else if (msg.kind == rekon_msgs::constraint_t::KIND_LOOP) c.kind = EdgeKind::Loop;
  else throw Error(name + " has unknown kind " + std::to_string(msg.kind) + "; dropped");
  c.from_id = msg.from_id;
  c.to_id = msg.to_id;
  const std::optional<Pose> relative = fromMsg(msg.relative);
  if (!relative) throw Error(name + " has a non-finite or non-unit relative pose; dropped");
  c.relative = *relative;
  const auto info = matrix6FromArray(msg.information);
  if (!info) throw Error(name + " has a non-finite information matrix; dropped");
  c.information = information_scale * *info;
  return c;
}

TrackedFrame trackedFrameFromMsg(const rekon_msgs::tracked_frame_t& msg) {
  const std::optional<Pose> pose = fromMsg(msg.pose_in_keyframe);
  if (!pose) throw Error("tracked frame " + std::to_string(msg.frame_id) + " has a non-finite or non-unit pose; dropped");
  if (!std::isfinite(msg.timestamp))
    throw Error("tracked frame " + std::to_string(msg.frame_id) + " has a non-finite timestamp; dropped");
  return {msg.frame_id, msg.timestamp, msg.keyframe_id, *pose, msg.state == rekon_msgs::tracked_frame_t::STATE_LOST};
}

ExternalConstraint externalConstraintFromMsg(const rekon_msgs::external_constraint_t& msg) {
  ExternalConstraint e;
  e.source = msg.source.empty() ? "an unnamed sender" : msg.source;
  e.sequence = msg.sequence;
  e.from_id = msg.from_id;
  e.to_id = msg.to_id;
  const std::string from = "external constraint " + std::to_string(msg.sequence) + " from " + e.source;
  if (msg.kind == rekon_msgs::external_constraint_t::KIND_LOOP) {
    e.kind = ExternalConstraint::Kind::Loop;
    e.name = from + " (loop " + std::to_string(msg.from_id) + " -> " + std::to_string(msg.to_id) + ")";
    if (msg.from_id == msg.to_id) throw Error(e.name + " links a keyframe to itself; dropped (name two keyframes)");
  } else if (msg.kind == rekon_msgs::external_constraint_t::KIND_PRIOR) {
    e.kind = ExternalConstraint::Kind::Prior;
    e.name = from + " (prior on keyframe " + std::to_string(msg.to_id) + ")";
  } else {
    throw Error(from + " has unknown kind " + std::to_string(msg.kind) + "; dropped (KIND_LOOP or KIND_PRIOR)");
  }
  const std::optional<Pose> pose = fromMsg(msg.pose);
  if (!pose) throw Error(e.name + " has a non-finite pose or a quaternion that is not unit; dropped");
  e.pose = *pose;
  const auto info = matrix6FromArray(msg.information);
  if (!info) throw Error(e.name + " has a non-finite information matrix; dropped");
  e.information = *info;
  return e;
}

Constraint edgeOf(const ExternalConstraint& e, int64_t anchor, const Pose& anchor_pose) {
  Constraint c;
  c.kind = EdgeKind::Loop;
  c.information = e.information;
  c.to_id = e.to_id;
  if (e.kind == ExternalConstraint::Kind::Loop) {
    c.from_id = e.from_id;
    c.relative = e.pose;
  } else {
    c.from_id = anchor;
    c.relative = orthonormalised(anchor_pose.inverse() * e.pose);
  }
  return c;
}

rekon_msgs::graph_update_t graphUpdateMsg(const PoseGraph& graph, int64_t version, bool final_update) {
  rekon_msgs::graph_update_t msg{};
  msg.version = version;
  msg.final_update = final_update;
  for (const auto& [id, pose] : graph.poses()) {
    msg.keyframe_ids.push_back(id);
    msg.poses.push_back(toMsg(pose));
  }
  msg.num_keyframes = static_cast<int32_t>(msg.keyframe_ids.size());
  return msg;
}

Trajectory frameTrajectory(const PoseGraph& graph, std::vector<TrackedFrame> frames, size_t* missing_keyframe) {
  return frameTrajectory(graph.poses(), std::move(frames), missing_keyframe);
}

Trajectory frameTrajectory(const std::vector<std::pair<int64_t, Pose>>& keyframe_poses, std::vector<TrackedFrame> frames,
                           size_t* missing_keyframe) {
  std::sort(frames.begin(), frames.end(), [](const TrackedFrame& a, const TrackedFrame& b) { return a.frame_id < b.frame_id; });
  Trajectory out;
  out.reserve(frames.size());
  size_t missing = 0;
  const auto by_id = [](const std::pair<int64_t, Pose>& kf, int64_t id) { return kf.first < id; };
  for (const TrackedFrame& f : frames) {
    if (f.lost) continue;  // its pose is the last good one, not where the camera was
    const auto kf = std::lower_bound(keyframe_poses.begin(), keyframe_poses.end(), f.keyframe_id, by_id);
    if (kf == keyframe_poses.end() || kf->first != f.keyframe_id) {
      ++missing;
      continue;
    }
    out.push_back({f.timestamp, orthonormalised(kf->second * f.pose_in_keyframe)});
  }
  if (missing_keyframe) *missing_keyframe = missing;
  return out;
}

}  // namespace rekon::optimiser
