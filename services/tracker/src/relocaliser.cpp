#include "rekon/tracker/relocaliser.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <numbers>
#include <utility>

namespace rekon::tracker {

void Relocaliser::addKeyframe(std::shared_ptr<const Keyframe> keyframe, const std::optional<OdometryConstraint>& incoming) {
  detector_.addKeyframe(std::move(keyframe), incoming);
  ++size_;
}

void Relocaliser::addIndexed(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming) {
  detector_.addIndexed(id, pose_world, incoming);
  ++size_;
}

void Relocaliser::updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses) {
  detector_.updateGraph(version, std::move(poses));
}

Relocalisation Relocaliser::placed(const CandidateCheck& accepted, int candidates_tried) const {
  Relocalisation r;
  r.edge = *accepted.constraint;
  r.pose_world = orthonormalised(detector_.estimate(accepted.candidate_id) * r.edge.relative);
  r.candidates_tried = candidates_tried;
  return r;
}

void Relocaliser::restart() {
  next_ = 0;
  tried_ = 0;
}

std::vector<int64_t> Relocaliser::ranked(const std::optional<Pose>& guess_world) const {
  std::vector<int64_t> ids = detector_.ids();
  if (!guess_world) return ids;
  std::vector<std::pair<double, int64_t>> by_distance;
  for (const int64_t id : ids)
    by_distance.emplace_back((detector_.estimate(id).translation() - guess_world->translation()).norm(), id);
  std::sort(by_distance.begin(), by_distance.end());
  for (size_t i = 0; i < ids.size(); ++i) ids[i] = by_distance[i].second;
  return ids;
}

std::vector<Pose> Relocaliser::guesses(int64_t candidate, const std::optional<Pose>& guess_world) const {
  // At the candidate, and a step of the odometry's motion around it either
  // way: a camera between keyframes, or beyond the last one, starts inside the
  // coarse level's basin of one of them.
  std::vector<Pose> out{Pose::Identity()};
  for (const Pose& step : detector_.odometryNeighbours(candidate)) {
    out.push_back(step);
    out.push_back(step.inverse());
  }
  if (guess_world) out.push_back(orthonormalised(detector_.estimate(candidate).inverse() * *guess_world));
  return out;
}

std::optional<Relocalisation> Relocaliser::relocalise(const Keyframe& query, const std::optional<Pose>& guess_world,
                                                      double budget_ms) {
  const std::vector<int64_t> ids = ranked(guess_world);
  if (ids.empty()) return std::nullopt;
  const auto start = std::chrono::steady_clock::now();
  const auto spent_ms = [&] {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  };
  for (size_t n = 0; n < ids.size() && (n == 0 || spent_ms() < budget_ms); ++n) {
    const int64_t candidate = ids[next_++ % ids.size()];
    ++tried_;
    const CandidateCheck c = detector_.check(candidate, query, guesses(candidate, guess_world));
    spdlog::debug("relocalisation of frame {} against keyframe {}: {} (ln det ratios coarse {:.3f}, fine {:.3f})",
                  query.frame_id, candidate, c.accepted ? "accepted" : c.reason, c.best_coarse_ratio, c.best_fine_ratio);
    if (c.accepted) return placed(c, tried_);
  }
  return std::nullopt;
}

std::optional<Relocalisation> Relocaliser::reuse(const Keyframe& query, int64_t current_id, const Pose& in_current,
                                                 const KeyframeParams& params) {
  const Pose at = orthonormalised(detector_.estimate(current_id) * in_current);
  const double max_angle = params.reuse_angle_deg * std::numbers::pi / 180.0;
  std::vector<std::pair<double, int64_t>> near;
  const std::vector<int64_t> ids = detector_.ids();
  for (const int64_t id : ids) {
    if (id == current_id || id > ids.back() - params.reuse_exclude_recent) continue;
    const Pose other = detector_.estimate(id);
    const double d = translationDistance(other, at);
    if (d <= params.reuse_radius && rotationAngle(other, at) <= max_angle) near.emplace_back(d, id);
  }
  std::sort(near.begin(), near.end());
  near.resize(std::min(near.size(), static_cast<size_t>(params.reuse_candidates)));
  int tried = 0;
  for (const auto& [distance, candidate] : near) {
    ++tried;
    ++reuse_checks_;
    // From the candidate itself and from where the estimates put the frame, as a loop check starts.
    const Pose guess = orthonormalised(detector_.estimate(candidate).inverse() * at);
    const CandidateCheck c = detector_.check(candidate, query, {Pose::Identity(), guess});
    spdlog::debug("keyframe reuse: frame {} against keyframe {} ({:.3f} m away): {} (ln det ratios coarse {:.3f}, fine "
                  "{:.3f})",
                  query.frame_id, candidate, distance, c.accepted ? "accepted" : c.reason, c.best_coarse_ratio,
                  c.best_fine_ratio);
    if (c.accepted) return placed(c, tried);
  }
  return std::nullopt;
}

}  // namespace rekon::tracker
