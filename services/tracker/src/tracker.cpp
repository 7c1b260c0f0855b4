#include "rekon/tracker/tracker.hpp"

#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/relocaliser.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace rekon::tracker {
namespace {

double radians(double deg) { return deg * std::numbers::pi / 180.0; }

double rotationAngleOf(const Pose& p) { return rotationAngle(Pose::Identity(), p); }

}  // namespace

const char* toString(LostReason reason) {
  switch (reason) {
    case LostReason::None: return "none";
    case LostReason::NoDepth: return "no valid depth";
    case LostReason::BlackImage: return "black image";
    case LostReason::AlignmentFailed: return "alignment failed";
    case LostReason::TooLittleOverlap: return "too little overlap with the keyframe";
    case LostReason::JumpBeyondBasin: return "jump beyond the convergence basin";
    case LostReason::LargeResidual: return "large residual after alignment";
    case LostReason::Relocalising: return "relocalising against the session";
    case LostReason::GapInTheData: return "gap in the data";
  }
  return "unknown";
}

Tracker::Tracker(const TrackerParams& params, std::shared_ptr<KeyframeCache> keyframes)
    : params_(params), aligner_(params.aligner),
      relocaliser_(std::make_unique<Relocaliser>(params, std::move(keyframes))) {
  params_.validate();
}

Tracker::~Tracker() = default;

void Tracker::addStoredKeyframe(std::shared_ptr<const Keyframe> keyframe, const std::optional<OdometryConstraint>& incoming) {
  next_keyframe_id_ = std::max(next_keyframe_id_, keyframe->id + 1);
  relocaliser_->addKeyframe(std::move(keyframe), incoming);
}

void Tracker::addIndexedKeyframe(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming) {
  next_keyframe_id_ = std::max(next_keyframe_id_, id + 1);
  relocaliser_->addIndexed(id, pose_world, incoming);
}

int64_t Tracker::keyframeReuseChecks() const { return relocaliser_->reuseChecks(); }

void Tracker::relocaliseFirstFrame(int frames) { relocalise_first_within_ = frames; }

void Tracker::localiseOnly() {
  localise_only_ = true;
  relocalise_first_within_ = std::max(relocalise_first_within_, 1);
}

void Tracker::updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses) {
  relocaliser_->updateGraph(version, std::move(poses));
}

std::shared_ptr<Keyframe> Tracker::keyframeOf(const RgbdFrame& frame, int64_t id) const {
  auto kf = std::make_shared<Keyframe>();
  kf->id = id;
  kf->frame_id = frame.id;
  kf->timestamp = frame.timestamp;
  kf->pyramid = current_;
  kf->reference = KeyframeReference(kf->pyramid, params_.aligner);
  return kf;
}

std::shared_ptr<const Keyframe> Tracker::makeKeyframe(const RgbdFrame& frame, const Pose& pose_world,
                                                      std::optional<double> incoming_entropy) {
  return makeKeyframe(keyframeOf(frame, next_keyframe_id_), pose_world, incoming_entropy);
}

std::shared_ptr<const Keyframe> Tracker::makeKeyframe(std::shared_ptr<Keyframe> kf, const Pose& pose_world,
                                                      std::optional<double> incoming_entropy) {
  ++next_keyframe_id_;
  kf->pose_world = orthonormalised(pose_world);  // products of many poses drift off SO(3)
  last_in_keyframe_ = Pose::Identity();
  reference_entropy_.reset();
  lastGoodIsKeyframe(incoming_entropy);
  return kf;
}

void Tracker::lastGoodIsKeyframe(std::optional<double> incoming_entropy) {
  last_good_in_pyramid_ = false;
  last_covariance_ = Matrix6d::Zero();
  last_entropy_ = incoming_entropy;
}

void Tracker::startFrom(std::shared_ptr<const Keyframe> keyframe, double timestamp) {
  keyframe_ = std::move(keyframe);
  last_in_keyframe_ = Pose::Identity();
  reference_entropy_.reset();
  velocity_ = Pose::Identity();
  velocity_dt_ = 0.0;
  last_good_timestamp_ = timestamp;
  lost_in_a_row_ = 0;
  lastGoodIsKeyframe(std::nullopt);
}

void Tracker::resumeOdometry(std::shared_ptr<const Keyframe> keyframe, const OdometryState& state) {
  keyframe_ = std::move(keyframe);
  last_in_keyframe_ = state.in_keyframe;
  velocity_ = state.velocity;
  velocity_dt_ = state.velocity_dt;
  last_good_timestamp_ = state.timestamp;
  reference_entropy_ = state.reference_entropy;
  lost_in_a_row_ = 0;
  lastGoodIsKeyframe(state.keyframe_entropy);
  resume_at_.reset();
}

bool Tracker::relocalise(const RgbdFrame& frame, const std::optional<Pose>& guess_world, TrackResult& r,
                         spdlog::level::level_enum log_level) {
  if (relocaliser_->size() == 0) return false;
  std::shared_ptr<Keyframe> kf = keyframeOf(frame, next_keyframe_id_);
  const auto found = relocaliser_->relocalise(*kf, guess_world, params_.lost.relocalise_budget_ms);
  if (!found) return false;
  relocaliser_->restart();
  ++next_keyframe_id_;
  kf->pose_world = found->pose_world;
  startFrom(kf, frame.timestamp);
  OdometryConstraint edge;
  edge.from_id = found->edge.from_id;
  edge.to_id = kf->id;
  edge.relative = found->edge.relative;
  edge.information = found->edge.information;
  edge.valid_pixels = found->edge.valid_pixels;
  r = TrackResult{};
  r.frame_id = frame.id;
  r.timestamp = frame.timestamp;
  r.relocalised_from = edge;
  reportStartedKeyframe(r);
  spdlog::log(log_level, "frame {}: relocalised against keyframe {} ({} candidates tried; ln det ratios coarse {:.2f}, fine {:.2f})",
              frame.id, edge.from_id, found->candidates_tried, found->edge.coarse_ratio, found->edge.fine_ratio);
  return true;
}

bool Tracker::reuseKeyframe(const Keyframe& query, const AlignResult& aligned, TrackResult& r) {
  const auto found = relocaliser_->reuse(query, keyframe_->id, aligned.pose, params_.keyframe);
  if (!found) return false;
  const int64_t left = keyframe_->id, reused = found->edge.from_id;
  // The frame in the reused keyframe (A, the loop check's) and in the one it
  // was tracked against (B): the reused keyframe's pose in that one's frame is
  // X = A B^-1, and with right perturbations a of A and b of B,
  // X exp(xi) = A exp(a) exp(-b) B^-1, so xi = Ad(B) (a - b).
  const Pose& in_reused = found->edge.relative;
  const Matrix6d reuse_covariance = found->edge.information.inverse();
  const Matrix6d carry = adjoint(aligned.pose);
  if (!reuse_edges_sent_.count(std::minmax(left, reused)) && !relocaliser_->odometryLinked(left, reused)) {
    OdometryConstraint edge;
    edge.from_id = reused;
    edge.to_id = left;
    edge.relative = orthonormalised(in_reused * aligned.pose.inverse());
    edge.information = (carry * (reuse_covariance + aligned.covariance()) * carry.transpose()).inverse();
    edge.entropy = entropyOfInformation(edge.information);
    edge.valid_pixels = found->edge.valid_pixels;
    r.reuse_edge = edge;
    reuse_edges_sent_.insert(std::minmax(left, reused));
  }
  // The frame is the last good one, aligned against the reused keyframe; the
  // motion model goes on (velocity_ is the camera's, whatever the reference).
  keyframe_ = relocaliser_->keyframe(reused);
  last_in_keyframe_ = in_reused;
  last_covariance_ = reuse_covariance;
  last_entropy_ = entropyOfInformation(found->edge.information);
  reference_entropy_ = last_entropy_;  // H(kf, t) of the next frames against the frame's (History::restore takes the same)
  std::swap(last_good_, current_);
  last_good_in_pyramid_ = true;
  r.keyframe_reused = true;
  r.pose_in_keyframe = in_reused;
  r.covariance = reuse_covariance;
  r.keyframe_id = reused;
  r.keyframe_pose_world = keyframe_->pose_world;
  r.pose_world = keyframe_->pose_world * in_reused;
  spdlog::debug("frame {}: keyframe {} reused instead of a new one ({:.3f} m from it; ln det ratios coarse {:.2f}, fine "
                "{:.2f})",
                query.frame_id, reused, in_reused.translation().norm(), found->edge.coarse_ratio, found->edge.fine_ratio);
  return true;
}

void Tracker::reportStartedKeyframe(TrackResult& r) const {
  r.state = TrackingState::Ok;
  r.new_keyframe = true;
  r.keyframe_id = keyframe_->id;
  r.keyframe_pose_world = keyframe_->pose_world;
  r.pose_world = keyframe_->pose_world;
}

bool Tracker::reanchor(const RgbdFrame& frame, const Pose& pose_world, TrackResult& r) {
  const Pose velocity = velocity_;
  const double velocity_dt = velocity_dt_;
  relocaliser_->restart();  // nearest `pose_world` first, not where an earlier search stopped
  if (!relocalise(frame, pose_world, r, spdlog::level::debug)) return false;  // one a keyframe: not news
  velocity_ = velocity;  // the camera's motion, whichever keyframe it is tracked against
  velocity_dt_ = velocity_dt;
  r.reanchored = true;
  return true;
}

bool Tracker::entropyRatioBelow(double entropy, double threshold) const {
  // H(kf,t) / H(kf,kf+1) < threshold, written so that it also holds when the
  // entropies are positive (few pixels, large covariance): the estimate's
  // entropy grew by more than (1 - threshold) of the reference's magnitude.
  if (!reference_entropy_) return false;
  return entropy - *reference_entropy_ > (1.0 - threshold) * std::abs(*reference_entropy_);
}

bool Tracker::keyframeDue(const AlignResult& aligned) const {
  const auto& kp = params_.keyframe;
  if (aligned.pose.translation().norm() > kp.max_translation) return true;
  if (rotationAngleOf(aligned.pose) > radians(kp.max_rotation_deg)) return true;
  return kp.criterion == "entropy_ratio" && entropyRatioBelow(aligned.entropy, kp.entropy_ratio);
}

TrackResult Tracker::track(const RgbdFrame& frame, const Intrinsics& k) {
  TrackResult r = trackFrame(frame, k);
  if (r.new_keyframe && !localise_only_) relocaliser_->addKeyframe(keyframe_, r.odometry);
  return r;
}

TrackResult Tracker::trackFrame(const RgbdFrame& frame, const Intrinsics& k) {
  const auto& ap = params_.aligner;
  current_.build(frame, k, ap.finest_level, ap.builtCoarsestLevel(k.width, k.height), ap.min_depth, ap.max_depth);

  TrackResult r;
  r.frame_id = frame.id;
  r.timestamp = frame.timestamp;
  LostReason reason = untrackableReason();
  const bool trackable = reason == LostReason::None;
  if (!keyframe_) {
    startTracking(frame, reason, r);
    return r;
  }

  if (trackable && frame.timestamp - last_good_timestamp_ > params_.lost.max_gap_s) reason = LostReason::GapInTheData;
  AlignResult aligned;
  if (reason == LostReason::None) {
    const Pose prediction = last_in_keyframe_ * predictedMotion(frame.timestamp);
    aligned = aligner_.align(keyframe_->reference, current_, prediction, coarsestLevelFor(frame.timestamp));
    reportAlignment(aligned, r);
    reason = alignmentLostReason(aligned, prediction);
  }
  if (reason == LostReason::None)
    followAlignment(frame, aligned, r);
  else if (!(reason == LostReason::GapInTheData && bridgeGap(frame, r)) &&
           (!trackable || !relocalise(frame, keyframe_->pose_world * last_in_keyframe_, r)))
    markLost(frame, reason, trackable, r);
  return r;
}

bool Tracker::bridgeGap(const RgbdFrame& frame, TrackResult& r) {
  if (localise_only_ || !last_entropy_) return false;
  const KeyframeReference built = last_good_in_pyramid_ ? KeyframeReference(last_good_, params_.aligner) : KeyframeReference();
  const KeyframeReference& reference = last_good_in_pyramid_ ? built : keyframe_->reference;
  const RgbdPyramid& reference_pyramid = last_good_in_pyramid_ ? last_good_ : keyframe_->pyramid;
  std::shared_ptr<Keyframe> kf = keyframeOf(frame, next_keyframe_id_);  // its reference aligns the pair back
  const LoopClosureParams& lp = params_.loop;
  const double reference_log_det = logDetOfEntropy(*last_entropy_);
  const int level = std::min({params_.aligner.gap_coarsest_level, reference.coarsestLevel(), current_.coarsestLevel()});
  const double gap_s = frame.timestamp - last_good_timestamp_;
  std::optional<AlignResult> best;
  // The whole gap extrapolated (on a smooth path it lands in the basin, where
  // the camera standing still would be 0.3 m and 20 degrees off after 1.1 s
  // of the room's loop), and the camera standing still; each from the gap's
  // level and from the usual one (whose basin is narrower, but which lands
  // where level 4 strays, on the room once in six gaps).
  const Pose extrapolated = predictedMotion(frame.timestamp, std::numeric_limits<double>::infinity());
  for (const auto& [start, from] : {std::pair{extrapolated, level}, std::pair{extrapolated, params_.aligner.coarsest_level},
                                    std::pair{Pose::Identity(), level}}) {
    const AlignResult a = aligner_.align(reference, current_, start, from);
    if (!a.valid || a.valid_pixels < lp.min_pixel_ratio * a.selected_pixels ||
        !informationPasses(logDetOfEntropy(a.entropy), reference_log_det, lp.fine_entropy_ratio) ||
        (best && a.entropy >= best->entropy))  // the better-determined one (DVO-SLAM's keepBest)
      continue;
    const AlignResult back = aligner_.align(kf->reference, reference_pyramid, a.pose.inverse());
    if (back.valid && (back.pose * a.pose).translation().norm() <= lp.max_cross_check_m) best = a;
  }
  if (!best) {
    spdlog::debug("frame {}: {:.2f} s after the last good frame, no start validated across the gap", frame.id, gap_s);
    return false;
  }
  // last_in_keyframe_ * best->pose, right perturbations: the first factor's
  // error carried through the second, plus the second's.
  const Matrix6d carry = adjoint(best->pose.inverse());
  OdometryConstraint c;
  c.from_id = keyframe_->id;
  c.to_id = kf->id;
  c.relative = orthonormalised(last_in_keyframe_ * best->pose);
  c.information = (carry * last_covariance_ * carry.transpose() + best->covariance()).inverse();
  c.entropy = entropyOfInformation(c.information);
  c.valid_pixels = best->valid_pixels;
  kf->pose_world = orthonormalised(keyframe_->pose_world * c.relative);
  ++next_keyframe_id_;
  keyframe_ = kf;
  last_in_keyframe_ = Pose::Identity();
  reference_entropy_.reset();
  lastGoodIsKeyframe(c.entropy);
  velocity_ = best->pose;  // the motion over the gap, scaled down to the next frame's interval
  velocity_dt_ = gap_s;
  last_good_timestamp_ = frame.timestamp;
  lost_in_a_row_ = 0;
  r.odometry = c;
  reportStartedKeyframe(r);
  spdlog::info("frame {}: aligned across a gap of {:.2f} s in the data ({:.2f} m, {:.1f} degrees from the last good frame)",
               frame.id, gap_s, best->pose.translation().norm(), rotationAngleOf(best->pose) * 180.0 / std::numbers::pi);
  return true;
}

void Tracker::startTracking(const RgbdFrame& frame, LostReason reason, TrackResult& r) {
  if (resume_at_ && reason == LostReason::None) {
    const Pose at = *resume_at_;
    resume_at_.reset();
    if (relocalise(frame, at, r)) return;
    spdlog::warn("frame {}: not relocalised against the keyframes near the last pose before the restart; new keyframe "
                 "there (no odometry edge)",
                 frame.id);
    keyframe_ = makeKeyframe(frame, at);
    last_good_timestamp_ = frame.timestamp;
    reportStartedKeyframe(r);
    r.keyframe_reset = true;
    return;
  }
  if (relocalise_first_within_ > 0) {
    ++frames_before_first_;
    if (reason == LostReason::None && relocalise(frame, std::nullopt, r)) return;
    r.lost_reason = reason == LostReason::None ? LostReason::Relocalising : reason;
    gave_up_ = !localise_only_ && frames_before_first_ >= relocalise_first_within_;
    return;
  }
  if (reason != LostReason::None) {
    r.lost_reason = reason;
    return;
  }
  keyframe_ = makeKeyframe(frame, Pose::Identity());
  last_good_timestamp_ = frame.timestamp;
  r.state = TrackingState::Ok;
  r.new_keyframe = true;
  r.keyframe_id = keyframe_->id;
}

int Tracker::coarsestLevelFor(double timestamp) const {
  const auto& ap = params_.aligner;
  if (!(timestamp - last_good_timestamp_ > ap.gap_coarse_s)) return ap.coarsest_level;
  return std::min(keyframe_->reference.coarsestLevel(), current_.coarsestLevel());
}

Pose Tracker::predictedMotion(double timestamp, double max_periods) const {
  // `periods`: this gap in units of the one velocity_ was measured over.
  // Within a factor of 1.5 of it is timestamp jitter: velocity_ as it is, as
  // for every frame of a recording without drops.
  constexpr double kJitter = 1.5;
  if (!(velocity_dt_ > 0)) return velocity_;
  const double periods = (timestamp - last_good_timestamp_) / velocity_dt_;
  if (!(periods > 0)) return Pose::Identity();
  if (periods < kJitter && periods > 1.0 / kJitter) return velocity_;
  return expSe3(std::min(periods, max_periods) * logSe3(velocity_));
}

LostReason Tracker::untrackableReason() const {
  const auto& lp = params_.lost;
  if (current_.validDepthFraction() < lp.min_valid_depth_fraction) return LostReason::NoDepth;
  if (current_.meanIntensity() < lp.min_mean_intensity) return LostReason::BlackImage;
  return LostReason::None;
}

void Tracker::reportAlignment(const AlignResult& aligned, TrackResult& r) const {
  r.entropy = aligned.entropy;
  r.valid_pixels = aligned.valid_pixels;
  r.iterations = aligned.iterations;
  r.intensity_sigma = aligned.intensity_sigma;
  r.depth_sigma = aligned.depth_sigma;
  if (reference_entropy_ && aligned.valid) r.entropy_ratio = aligned.entropy / *reference_entropy_;
}

LostReason Tracker::alignmentLostReason(const AlignResult& aligned, const Pose& prediction) const {
  const auto& lp = params_.lost;
  const Pose correction = prediction.inverse() * aligned.pose;
  if (!aligned.valid) return LostReason::AlignmentFailed;
  if (aligned.valid_pixels < lp.min_overlap * aligned.selected_pixels) return LostReason::TooLittleOverlap;
  if (correction.translation().norm() > lp.max_frame_translation ||
      rotationAngleOf(correction) > radians(lp.max_frame_rotation_deg))
    return LostReason::JumpBeyondBasin;
  if ((aligned.intensity_sigma > lp.max_intensity_sigma || aligned.depth_sigma > lp.max_depth_sigma) &&
      entropyRatioBelow(aligned.entropy, lp.residual_entropy_ratio))
    return LostReason::LargeResidual;
  return LostReason::None;
}

void Tracker::markLost(const RgbdFrame& frame, LostReason reason, bool trackable, TrackResult& r) {
  ++lost_in_a_row_;
  if (reason != LostReason::GapInTheData) {
    // The motion before a gap is the last known one, for the next frame's bridgeGap().
    velocity_ = Pose::Identity();
    velocity_dt_ = 0.0;
  }
  r.state = TrackingState::Lost;
  r.lost_reason = reason;
  spdlog::debug("frame {}: lost ({})", frame.id, toString(reason));
  if (trackable && !localise_only_ && lost_in_a_row_ >= params_.lost.max_lost_frames) {
    // Re-initialising from the last good keyframe has not worked for too
    // long: restart from this frame at the last good pose.
    spdlog::warn("frame {}: lost for {} frames, new keyframe at the last good pose", frame.id, lost_in_a_row_);
    keyframe_ = makeKeyframe(frame, keyframe_->pose_world * last_in_keyframe_);
    velocity_ = Pose::Identity();
    velocity_dt_ = 0.0;
    last_good_timestamp_ = frame.timestamp;
    lost_in_a_row_ = 0;
    r.new_keyframe = true;
    r.keyframe_reset = true;
  } else {
    r.covariance = Matrix6d::Identity() * kLostVariance;
  }
  r.keyframe_id = keyframe_->id;
  r.pose_in_keyframe = last_in_keyframe_;
  r.keyframe_pose_world = keyframe_->pose_world;
  r.pose_world = keyframe_->pose_world * last_in_keyframe_;
}

void Tracker::followAlignment(const RgbdFrame& frame, const AlignResult& aligned, TrackResult& r) {
  lost_in_a_row_ = 0;
  velocity_ = last_in_keyframe_.inverse() * aligned.pose;
  velocity_dt_ = frame.timestamp - last_good_timestamp_;
  last_good_timestamp_ = frame.timestamp;
  r.state = TrackingState::Ok;
  if (!reference_entropy_) reference_entropy_ = aligned.entropy;
  r.entropy_ratio = aligned.entropy / *reference_entropy_;
  if (keyframeDue(aligned)) {
    if (localise_only_ && reanchor(frame, keyframe_->pose_world * aligned.pose, r)) return;
    std::shared_ptr<Keyframe> kf = keyframeOf(frame, next_keyframe_id_);
    if (params_.keyframe.reuse && !localise_only_ && reuseKeyframe(*kf, aligned, r)) return;
    OdometryConstraint c;
    c.from_id = keyframe_->id;
    c.relative = aligned.pose;
    c.information = aligned.information;
    c.entropy = aligned.entropy;
    c.valid_pixels = aligned.valid_pixels;
    keyframe_ = makeKeyframe(std::move(kf), keyframe_->pose_world * aligned.pose, aligned.entropy);
    c.to_id = keyframe_->id;
    r.odometry = c;
    r.new_keyframe = true;
  } else {
    last_in_keyframe_ = aligned.pose;
    r.pose_in_keyframe = aligned.pose;
    r.covariance = aligned.covariance();
    std::swap(last_good_, current_);  // current_ is built anew for the next frame
    last_good_in_pyramid_ = true;
    last_covariance_ = r.covariance;
    last_entropy_ = aligned.entropy;
  }
  r.keyframe_id = keyframe_->id;
  r.keyframe_pose_world = keyframe_->pose_world;
  r.pose_world = keyframe_->pose_world * r.pose_in_keyframe;
}

}  // namespace rekon::tracker
