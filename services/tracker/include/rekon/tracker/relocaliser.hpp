#pragma once
// Relocalisation (issue 18): a frame that tracking cannot place is aligned to
// the keyframes one after another, from the candidate's pose, a step of the
// odometry either way around it and (after a loss) the last good pose, and
// validated exactly as a loop closure (LoopClosureDetector::check: coarse
// then fine stage against the odometry's information, cross-checked the
// other way round); the first accepted alignment places it. Every keyframe is a candidate: those nearest a guess
// of the pose first when there is one (the last good pose after a loss),
// else in id order (the first frame of a continued session, whose pose is
// unknown). A call stops once its time budget is spent and the next call
// goes on with the next candidates, so one search over many keyframes
// spreads over several frames.
#include <cstdint>
#include <memory>
#include <optional>
#include <unordered_map>
#include <vector>

#include "rekon/tracker/loop_closure.hpp"

namespace rekon::tracker {

struct Relocalisation {
  LoopConstraint edge;  // the frame's keyframe in the candidate's frame (edge.from_id: the candidate)
  Pose pose_world = Pose::Identity();  // the candidate's current estimate times edge.relative
  int candidates_tried = 0;            // in this search, over all calls
};

class Relocaliser {
 public:
  explicit Relocaliser(const TrackerParams& params, std::shared_ptr<KeyframeCache> cache = nullptr)
      : detector_(params, std::move(cache)) {}

  // Tracking thread only.
  void addKeyframe(std::shared_ptr<const Keyframe> keyframe, const std::optional<OdometryConstraint>& incoming);
  // One the shared cache indexes (LoopClosureDetector::addIndexed).
  void addIndexed(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming);
  // Any thread (the bus thread): the optimiser's poses.
  void updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses);
  size_t size() const { return size_; }

  // Checks candidates for `query` (a keyframe made of the frame, not yet in
  // the database) for at most `budget_ms` (at least one candidate).
  std::optional<Relocalisation> relocalise(const Keyframe& query, const std::optional<Pose>& guess_world, double budget_ms);
  // The next relocalise() starts a new search (from the first candidate).
  void restart();
  // Keyframe reuse (KeyframeParams::reuse): `query` (a keyframe made of the
  // frame, not yet in the database), at `in_current` in keyframe
  // `current_id`, checked as relocalise() checks against the keyframes other
  // than `current_id` whose estimated camera centre lies within reuse_radius
  // and orientation within reuse_angle_deg of its estimated pose, nearest
  // first, at most reuse_candidates of them; the first accepted.
  std::optional<Relocalisation> reuse(const Keyframe& query, int64_t current_id, const Pose& in_current,
                                      const KeyframeParams& params);
  // Candidates reuse() has checked so far.
  int64_t reuseChecks() const { return reuse_checks_; }
  std::shared_ptr<const Keyframe> keyframe(int64_t id) const { return detector_.keyframe(id); }
  bool odometryLinked(int64_t a, int64_t b) const { return detector_.odometryLinked(a, b); }

 private:
  std::vector<int64_t> ranked(const std::optional<Pose>& guess_world) const;
  // An accepted check as a relocalisation: the query at the candidate's estimate times the edge.
  Relocalisation placed(const CandidateCheck& accepted, int candidates_tried) const;
  // Initial poses of the query in `candidate` to align from.
  std::vector<Pose> guesses(int64_t candidate, const std::optional<Pose>& guess_world) const;

  LoopClosureDetector detector_;
  size_t size_ = 0;
  size_t next_ = 0;  // index into the ranked candidates where the search goes on
  int tried_ = 0;
  int64_t reuse_checks_ = 0;
};

}  // namespace rekon::tracker
