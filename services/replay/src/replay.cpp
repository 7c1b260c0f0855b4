#include "rekon/replay/replay.hpp"

#include <algorithm>
#include <cmath>

#include "rekon/common/error.hpp"

namespace rekon::replay {

void ReplayParams::validate() const {
  if (trajectory.empty() || target.empty()) throw Error("rekon-replay: give --trajectory FILE and --target FILE (TUM format)");
  if (!(keyframe_translation > 0 && keyframe_rotation_deg > 0))
    throw Error("rekon-replay: keyframe distance limits must be positive");
  if (update_every_keyframes < 0) throw Error("rekon-replay: --update-every must not be negative");
  if (!(stream_alpha >= 0 && stream_alpha <= 1)) throw Error("rekon-replay: --stream-alpha must lie in [0, 1]");
  if (final_updates < 1) throw Error("rekon-replay: --final-updates must be at least 1 (the last one reaches the target)");
}

Pose interpolatePose(const Pose& a, const Pose& b, double alpha) {
  const Eigen::Quaterniond qa(a.linear()), qb(b.linear());
  return poseFromQuatTrans(qa.slerp(alpha, qb).normalized(),
                           (1 - alpha) * a.translation() + alpha * b.translation());
}

ReplayScript::ReplayScript(Trajectory source, Trajectory target, const ReplayParams& params, int64_t total_frames)
    : source_(std::move(source)), target_(std::move(target)), params_(params), total_frames_(std::max<int64_t>(1, total_frames)) {
  params_.validate();
  if (source_.empty()) throw Error("rekon-replay: the trajectory " + params_.trajectory + " is empty");
}

ReplayTracked ReplayScript::onFrame(int64_t frame_id, double timestamp) {
  ++frames_seen_;
  ReplayTracked out;
  out.frame_id = frame_id;
  out.timestamp = timestamp;
  const int i = nearestInTime(source_, timestamp, params_.max_time_difference);
  if (i < 0) {  // no pose for this frame: lost, as the tracker reports it
    out.lost = true;
    out.keyframe_id = keyframes_.empty() ? 0 : keyframes_.back().id;
    return out;
  }
  const Pose world = source_[static_cast<size_t>(i)].pose;
  const bool new_keyframe =
      keyframes_.empty() || translationDistance(keyframes_.back().source, world) > params_.keyframe_translation ||
      rotationAngle(keyframes_.back().source, world) * 180.0 / M_PI > params_.keyframe_rotation_deg;
  if (new_keyframe) {
    const int j = nearestInTime(target_, timestamp, params_.max_time_difference);
    keyframes_.push_back({static_cast<int64_t>(keyframes_.size()), world, j < 0 ? world : target_[static_cast<size_t>(j)].pose});
    out.new_keyframe_world = world;
    if (params_.update_every_keyframes > 0 && ++keyframes_since_update_ >= params_.update_every_keyframes) {
      keyframes_since_update_ = 0;
      update_due_ = true;
    }
  }
  out.keyframe_id = keyframes_.back().id;
  out.pose_in_keyframe = keyframes_.back().source.inverse() * world;
  return out;
}

ReplayGraphUpdate ReplayScript::updateAt(double alpha, bool final_update) {
  ReplayGraphUpdate u;
  u.version = ++version_;
  u.final_update = final_update;
  for (const Keyframe& k : keyframes_) u.poses.emplace_back(k.id, interpolatePose(k.source, k.target, alpha));
  return u;
}

std::optional<ReplayGraphUpdate> ReplayScript::dueUpdate() {
  if (!update_due_) return std::nullopt;
  update_due_ = false;
  const double progress = std::min(1.0, static_cast<double>(frames_seen_) / static_cast<double>(total_frames_));
  return updateAt(params_.stream_alpha * progress, false);
}

std::vector<ReplayGraphUpdate> ReplayScript::finalUpdates() {
  std::vector<ReplayGraphUpdate> out;
  for (int k = 1; k <= params_.final_updates; ++k) {
    const double alpha = params_.stream_alpha + (1.0 - params_.stream_alpha) * k / params_.final_updates;
    out.push_back(updateAt(k == params_.final_updates ? 1.0 : alpha, k == params_.final_updates));
  }
  return out;
}

}  // namespace rekon::replay
