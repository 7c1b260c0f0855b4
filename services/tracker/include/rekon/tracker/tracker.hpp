#pragma once
// DVO frame-to-keyframe tracking (Kerl, Sturm, Cremers, IROS 2013): every
// frame is densely aligned to the current DVO keyframe from a constant-
// velocity prediction; a new keyframe starts when the entropy ratio of the
// estimate drops or the camera moved too far from the keyframe, and each new
// keyframe brings an odometry constraint to its predecessor.
#include <cstdint>
#include <memory>
#include <algorithm>
#include <optional>
#include <set>
#include <unordered_map>
#include <utility>

#include <spdlog/common.h>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/rgbd_frame.hpp"
#include "rekon/common/se3.hpp"
#include "rekon/tracker/dense_aligner.hpp"
#include "rekon/tracker/keyframe_reference.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/rgbd_pyramid.hpp"

namespace rekon::tracker {

enum class TrackingState { Ok, Lost };

enum class LostReason {
  None,
  NoDepth,           // too few valid depth pixels in the frame
  BlackImage,        // mean intensity too low to align photometrically
  AlignmentFailed,   // too few pixels or a singular system at the finest level
  TooLittleOverlap,  // too few keyframe pixels landed in the frame
  JumpBeyondBasin,   // the estimate moved too far from the prediction to be trusted
  LargeResidual,     // the aligned images still disagree
  Relocalising,      // a continued session's first frames, until one is relocalised
  GapInTheData,      // too long after the last good frame: the motion meanwhile is unknown
};
const char* toString(LostReason reason);

// A DVO keyframe: immutable once made, shared with loop-closure checks.
struct Keyframe {
  int64_t id = 0;
  int64_t frame_id = 0;
  double timestamp = 0.0;
  Pose pose_world = Pose::Identity();  // the tracker's odometry estimate when it was made
  RgbdPyramid pyramid;                 // the keyframe as the "current" side of an alignment
  KeyframeReference reference;         // the keyframe as the reference side
};

// Pose of keyframe `to_id` in the frame of `from_id` with its information
// (right perturbation, (v, w) order, as AlignResult::information).
struct OdometryConstraint {
  int64_t from_id = 0;
  int64_t to_id = 0;
  Pose relative = Pose::Identity();
  Matrix6d information = Matrix6d::Zero();
  double entropy = 0.0;  // entropyOfInformation(information)
  int valid_pixels = 0;  // pixels that constrained it
};

// Where a killed tracker's odometry stood, from its journal's last tracked
// frames: a restart goes on from here as the killed one would have
// (Tracker::resumeOdometry).
struct OdometryState {
  int64_t keyframe_id = -1;                 // the keyframe the last frame was tracked against
  Pose in_keyframe = Pose::Identity();      // the last frame, relative to it
  double timestamp = 0.0;                   // ...its timestamp
  // When the last frame is the keyframe's own: its incoming edge's entropy (a
  // gap after it is bridged from the keyframe); else none (the last frame's
  // images died with the killed instance: a gap is relocalised instead).
  std::optional<double> keyframe_entropy;
  Pose velocity = Pose::Identity();         // motion between the last two frames
  double velocity_dt = 0.0;                 // seconds between them (0: no velocity)
  std::optional<double> reference_entropy;  // of the keyframe's first aligned frame (keyframe selection)
};

struct TrackResult {
  int64_t frame_id = 0;
  double timestamp = 0.0;
  int64_t keyframe_id = -1;  // -1 only while no keyframe exists yet
  // Camera-to-keyframe pose and its covariance (right perturbation, (v, w));
  // identity and zero for the frame that is itself the new keyframe. A lost
  // frame carries the last good pose and kLostVariance on the diagonal.
  Pose pose_in_keyframe = Pose::Identity();
  Matrix6d covariance = Matrix6d::Zero();
  TrackingState state = TrackingState::Lost;
  LostReason lost_reason = LostReason::None;
  bool new_keyframe = false;
  // The new keyframe was started after max_lost_frames lost frames, at the
  // last good pose: no odometry constraint links it to its predecessor.
  bool keyframe_reset = false;
  std::optional<OdometryConstraint> odometry;  // set when a keyframe followed its predecessor
  // Set when the frame was relocalised (relocaliser.hpp): its new keyframe's
  // validated edge from an earlier keyframe, published as a loop edge.
  std::optional<OdometryConstraint> relocalised_from;
  // localiseOnly(): a due keyframe placed by relocalising it against the map
  // (relocalised_from is its edge), not a relocalisation after a loss.
  bool reanchored = false;
  // A due keyframe was not made (TrackerParams::keyframe.reuse): the frame
  // validated against the existing keyframe `keyframe_id` near it, which
  // tracking goes on against. reuse_edge: that keyframe's edge to the one the
  // frame was tracked against before (the frame's two poses composed),
  // published as a loop edge; absent when odometry already links the two or
  // an earlier switch between them sent one.
  bool keyframe_reused = false;
  std::optional<OdometryConstraint> reuse_edge;
  Pose keyframe_pose_world = Pose::Identity();  // odometry estimate of the keyframe
  Pose pose_world = Pose::Identity();           // keyframe_pose_world * pose_in_keyframe
  double entropy = 0.0;                         // of the alignment, when one ran
  double entropy_ratio = 1.0;                   // H(kf, t) / H(kf, kf+1)
  int valid_pixels = 0;
  int iterations = 0;
  double intensity_sigma = 0.0;  // robust residual scales of the alignment
  double depth_sigma = 0.0;
};

class KeyframeCache;
class Relocaliser;

class Tracker {
 public:
  static constexpr double kLostVariance = 1e4;

  // `keyframes`: where the relocalisation candidates' images are held
  // (shared with the loop-closure worker); null: a cache of its own.
  explicit Tracker(const TrackerParams& params = {}, std::shared_ptr<KeyframeCache> keyframes = nullptr);
  ~Tracker();
  Tracker(const Tracker&) = delete;
  Tracker& operator=(const Tracker&) = delete;

  // Tracks one frame; never returns a NaN or non-orthonormal pose. Throws
  // rekon::Error only for a frame whose format does not match `k`.
  TrackResult track(const RgbdFrame& frame, const Intrinsics& k);

  // A continued session (issue 18): a keyframe of an earlier run, a
  // candidate for relocalisation; new keyframe ids continue past it.
  void addStoredKeyframe(std::shared_ptr<const Keyframe> keyframe, const std::optional<OdometryConstraint>& incoming);
  // The first keyframe is relocalised against the stored ones (frames before
  // it are lost: Relocalising); when none of the first `frames` frames is,
  // gaveUp() turns true.
  void relocaliseFirstFrame(int frames);
  // A restarted tracker (tracker.restarted): an earlier instance's keyframe,
  // indexed in the shared cache (KeyframeCache::addArchived), a candidate for
  // relocalisation; new keyframe ids continue past it.
  void addIndexedKeyframe(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming);
  // New keyframe ids start at `next_id` or later.
  void continueIdsFrom(int64_t next_id) { next_keyframe_id_ = std::max(next_keyframe_id_, next_id); }
  // The first trackable frame is relocalised against the keyframes nearest
  // `last_pose_world` (the killed instance's last pose); when none validates
  // it becomes a new keyframe there, with no odometry edge (keyframe_reset,
  // as after max_lost_frames): tracking always goes on.
  void resumeAt(const Pose& last_pose_world) { resume_at_ = last_pose_world; }
  // Better, when the killed instance's last frame was tracked and its keyframe
  // is archived: tracking goes on against `keyframe` from `state`, so the
  // first frame is odometry as without the kill (a frame that does not align
  // is lost, and relocalised, as any other).
  void resumeOdometry(std::shared_ptr<const Keyframe> keyframe, const OdometryState& state);
  bool gaveUp() const { return gave_up_; }
  // Localisation in a saved map (session.localise_only): the stored keyframes
  // are the map and stay the only relocalisation candidates. The first frame
  // is relocalised against them, and so is a lost one, however long that
  // takes (frames stay lost until then: no restart at a guessed pose). Each
  // keyframe tracking makes is placed by relocalising it against the stored
  // ones nearest its odometry pose, by odometry only when none validates
  // within tracker.lost_relocalise_budget_ms. The tracker's own keyframes are
  // kept only while frames track against them.
  void localiseOnly();
  // The optimiser's keyframe poses, for ranking and placing relocalisations (any thread).
  void updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses);

  std::shared_ptr<const Keyframe> currentKeyframe() const { return keyframe_; }
  int64_t keyframeCount() const { return next_keyframe_id_; }
  // Existing keyframes aligned to decide a reuse (KeyframeParams::reuse), each a loop check on this thread.
  int64_t keyframeReuseChecks() const;
  const TrackerParams& params() const { return params_; }

 private:
  // `incoming_entropy`: of the odometry constraint that made it, when one did.
  std::shared_ptr<const Keyframe> makeKeyframe(const RgbdFrame& frame, const Pose& pose_world,
                                               std::optional<double> incoming_entropy = std::nullopt);
  // The same for `kf`, made by keyframeOf(frame, next_keyframe_id_).
  std::shared_ptr<const Keyframe> makeKeyframe(std::shared_ptr<Keyframe> kf, const Pose& pose_world,
                                               std::optional<double> incoming_entropy);
  // A due keyframe's frame (`query`, keyframeOf it; `aligned` against
  // keyframe_) placed against an existing keyframe near it instead
  // (KeyframeParams::reuse); on success tracking goes on against that one and
  // `r` says so.
  bool reuseKeyframe(const Keyframe& query, const AlignResult& aligned, TrackResult& r);
  // keyframe_ (just made or adopted) is the last good frame.
  void lastGoodIsKeyframe(std::optional<double> incoming_entropy);
  // Tracking goes on from `keyframe` (a relocalised one), no motion known.
  void startFrom(std::shared_ptr<const Keyframe> keyframe, double timestamp);
  // current_ as a keyframe with id `id`, not yet adopted.
  std::shared_ptr<Keyframe> keyframeOf(const RgbdFrame& frame, int64_t id) const;
  TrackResult trackFrame(const RgbdFrame& frame, const Intrinsics& k);
  // The first frame: a keyframe at identity, or with relocaliseFirstFrame() a relocalised one.
  void startTracking(const RgbdFrame& frame, LostReason reason, TrackResult& r);
  // Relocalises current_ (nearest `guess_world` first); on success the frame
  // becomes the keyframe at the validated pose and `r` says so.
  bool relocalise(const RgbdFrame& frame, const std::optional<Pose>& guess_world, TrackResult& r,
                  spdlog::level::level_enum log_level = spdlog::level::info);
  // localiseOnly(): a due keyframe at `pose_world` (odometry) placed by the
  // map instead when one of the stored keyframes nearest it validates; the
  // motion model goes on.
  bool reanchor(const RgbdFrame& frame, const Pose& pose_world, TrackResult& r);
  // `r` is a good frame that is itself the new keyframe_ (relocalised or across a gap).
  void reportStartedKeyframe(TrackResult& r) const;
  bool keyframeDue(const AlignResult& aligned) const;
  bool entropyRatioBelow(double entropy, double threshold) const;

  // track(), piece by piece, in the order it calls them.
  // NoDepth or BlackImage for a frame (in current_) not worth aligning, else None.
  LostReason untrackableReason() const;
  // The alignment's statistics into the result.
  void reportAlignment(const AlignResult& aligned, TrackResult& r) const;
  // Why an alignment from `prediction` is not to be trusted; None when it is.
  LostReason alignmentLostReason(const AlignResult& aligned, const Pose& prediction) const;
  // A lost frame: the last good pose, and a new keyframe there after max_lost_frames.
  void markLost(const RgbdFrame& frame, LostReason reason, bool trackable, TrackResult& r);
  // A good frame: its pose, or a new keyframe with its odometry constraint when one is due.
  void followAlignment(const RgbdFrame& frame, const AlignResult& aligned, TrackResult& r);
  // A frame more than lost.max_gap_s after the last good one (frames
  // missing: the camera moved on, tracking did not fail) aligned to the last
  // good frame, the nearest view there is, from the gap's coarse level,
  // starting where the camera's motion would have taken it and where it was.
  // Validated as a loop closure is (LoopClosureParams: information against
  // the last good frame's own alignment, constraining pixels, the pair
  // aligned back), it becomes a keyframe whose odometry constraint spans the
  // gap; false when no start validates (then it is relocalised).
  bool bridgeGap(const RgbdFrame& frame, TrackResult& r);
  // The motion expected from the last good frame to a frame taken at
  // `timestamp`: velocity_, scaled to the time between them when frames were
  // dropped in between (a live source drops frames; the motion grows with
  // the gap). Regular frames get velocity_ itself. Beyond 8 periods the
  // extrapolation is no better than a guess for the basin of one alignment.
  // `max_periods`: the extrapolation's limit in units of velocity_dt_.
  Pose predictedMotion(double timestamp, double max_periods = 8.0) const;
  // The level a frame at `timestamp` starts aligning on: coarser after a gap
  // (AlignerParams::gap_coarsest_level, as far as both pyramids reach).
  int coarsestLevelFor(double timestamp) const;

  TrackerParams params_;
  DenseAligner aligner_;
  RgbdPyramid current_;
  std::shared_ptr<const Keyframe> keyframe_;
  int64_t next_keyframe_id_ = 0;
  Pose last_in_keyframe_ = Pose::Identity();  // last good frame, relative to keyframe_
  Pose velocity_ = Pose::Identity();          // motion between the last two good frames
  double velocity_dt_ = 0.0;                  // seconds between them (0: no velocity)
  double last_good_timestamp_ = 0.0;
  std::optional<double> reference_entropy_;   // H(kf, kf+1)
  // The last good frame for bridgeGap(): its pyramid when it is not keyframe_
  // itself (swapped with current_, no copy), the covariance of
  // last_in_keyframe_ and the entropy of its alignment (of keyframe_'s
  // incoming constraint when it is keyframe_; none after a restart or a
  // relocalisation).
  RgbdPyramid last_good_;
  bool last_good_in_pyramid_ = false;
  Matrix6d last_covariance_ = Matrix6d::Zero();
  std::optional<double> last_entropy_;
  int lost_in_a_row_ = 0;
  std::unique_ptr<Relocaliser> relocaliser_;  // every keyframe, stored and new
  int relocalise_first_within_ = 0;           // > 0: the first keyframe must be relocalised within this many frames
  int frames_before_first_ = 0;
  bool gave_up_ = false;
  bool localise_only_ = false;
  std::optional<Pose> resume_at_;  // resumeAt(), until the first trackable frame
  std::set<std::pair<int64_t, int64_t>> reuse_edges_sent_;  // (older, newer) keyframe ids
};

}  // namespace rekon::tracker
