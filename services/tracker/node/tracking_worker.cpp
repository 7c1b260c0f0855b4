#include "tracking_worker.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <filesystem>
#include <optional>

#include "rekon/common/camera.hpp"
#include "rekon/common/cpu_time.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/rgbd_frame.hpp"
#include "rekon/tracker/keyframe_archive.hpp"

namespace rekon::tracker {

TrackerSession TrackerSession::fromConfig(const Config& config) {
  TrackerSession s;
  s.dir = config.getString("session.dir");
  s.continued = config.getBool("session.continue");
  s.localise_only = config.getBool("session.localise_only");
  s.relocalise_frames = config.getInt("session.relocalise_frames");
  if (s.continued && s.dir.empty()) throw Error("session.continue needs session.dir (rekon run --continue DIR sets both)");
  // Spilled keyframes are files of the session's own names (keyframe_archive.hpp), removed at exit.
  const std::string spill = config.getString("tracker.keyframe_spill_dir");
  if (!s.dir.empty() && spill != KeyframeMemoryParams::kAutoSpillDir &&
      std::filesystem::weakly_canonical(spill) == std::filesystem::weakly_canonical(s.dir))
    throw Error("tracker.keyframe_spill_dir is the session folder " + s.dir + ": the keyframes spilled there would "
                "replace the session's own and be removed at exit; set it to another folder, or auto");
  if (s.localise_only && !s.continued)
    throw Error("session.localise_only localises in a saved session: it needs session.continue and session.dir "
                "(rekon run --continue DIR --localise-only sets them)");
  if (s.relocalise_frames < 1) throw Error("session.relocalise_frames must be at least 1");
  return s;
}

TrackingWorker::TrackingWorker(const TrackerParams& params, const TrackerSession& session, History& history,
                               LoopClosureWorker& loops, std::shared_ptr<KeyframeCache> keyframes, TrackerState* state)
    : session_(session), state_(state), history_(history), loops_(loops), keyframes_(keyframes),
      tracker_(params, std::move(keyframes)) {
  if (session_.continued) continueSession(params);
}

void TrackingWorker::addIndexedKeyframe(int64_t id, const Pose& pose_world,
                                        const std::optional<OdometryConstraint>& incoming) {
  std::lock_guard<std::mutex> lock(mutex_);
  tracker_.addIndexedKeyframe(id, pose_world, incoming);
}

void TrackingWorker::continueIdsFrom(int64_t next_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  tracker_.continueIdsFrom(next_id);
}

void TrackingWorker::resumeAt(const Pose& last_pose_world) {
  std::lock_guard<std::mutex> lock(mutex_);
  tracker_.resumeAt(last_pose_world);
  resuming_ = true;
}

void TrackingWorker::resumeOdometry(std::shared_ptr<const Keyframe> keyframe, const OdometryState& state) {
  std::lock_guard<std::mutex> lock(mutex_);
  tracker_.resumeOdometry(std::move(keyframe), state);
  resuming_ = true;
}

void TrackingWorker::restoreOdometry(const Trajectory& odometry) {
  std::lock_guard<std::mutex> lock(mutex_);
  totals_.odometry.insert(totals_.odometry.begin(), odometry.begin(), odometry.end());
  totals_.restored_frames = static_cast<int64_t>(odometry.size());
}

std::string TrackingWorker::resumedBy() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return resumed_by_;
}

void TrackingWorker::continueSession(const TrackerParams& params) {
  const std::vector<StoredKeyframe> stored = loadKeyframes(session_.dir, params.aligner);
  for (const StoredKeyframe& s : stored) {
    tracker_.addStoredKeyframe(s.keyframe, s.incoming);
    if (!session_.localise_only) loops_.addStored(s.keyframe, s.incoming);  // localising closes no loops
  }
  session_camera_ = stored.front().camera;
  stored_keyframes_ = stored.size();
  tracker_.relocaliseFirstFrame(session_.relocalise_frames);
  if (session_.localise_only) {
    // No optimiser runs: the map's poses are the session's newest ones.
    std::unordered_map<int64_t, Pose> map = loadMapPoses(session_.dir);
    size_t placed = 0;
    for (const StoredKeyframe& s : stored) placed += map.count(s.keyframe->id);
    if (placed < stored.size())
      spdlog::warn("session {}: {} of its {} DVO keyframes have no pose in anchors.txt; their odometry places them",
                   session_.dir, stored.size() - placed, stored.size());
    tracker_.updateGraph(0, std::move(map));
    tracker_.localiseOnly();
    spdlog::info("session {}: localising only (the session is read, never written)", session_.dir);
  }
  spdlog::info("session {}: {} DVO keyframes (ids {}..{}); relocalising the first frame against them", session_.dir,
               stored.size(), stored.front().keyframe->id, stored.back().keyframe->id);
}

void TrackingWorker::checkCamera(const Intrinsics& k) const {
  if (session_camera_ && !sameCamera(k, *session_camera_))
    throw Error(session_.dir + " was made with another camera (" + describeCamera(*session_camera_) +
                ", this run's: " + describeCamera(k) + "); continue it with the camera it was made with");
}

void TrackingWorker::keepInSession(const TrackResult& r, const Intrinsics& k) {
  if (tracker_.gaveUp())
    throw Error(fmt::format("none of the first {} frames relocalised against the {} keyframes of {}: is the camera "
                            "in the space that session scanned? (session.relocalise_frames sets how long to try)",
                            session_.relocalise_frames, stored_keyframes_, session_.dir));
  if (!session_.dir.empty() && !session_.localise_only && r.new_keyframe)
    saveKeyframe(session_.dir, *tracker_.currentKeyframe(), r.odometry, k);
}

void TrackingWorker::updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses) {
  tracker_.updateGraph(version, poses);
  loops_.updateGraph(version, std::move(poses));
}

std::optional<std::string> TrackingWorker::failure() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return failure_;
}

bool TrackingWorker::track(const rekon_msgs::frame_t& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (failure_) return false;
  try {
    return trackLocked(msg);
  } catch (const Error& e) {  // the session's: the service stops with it (failure())
    failure_ = e.what();
    return false;
  }
}

void TrackingWorker::noteFirstPoseAfterRestart(const TrackResult& r) {
  resuming_ = false;
  resumed_by_ = r.relocalised_from ? "relocalised" : r.keyframe_reset ? "new keyframe" : "odometry";
  const std::string how =
      r.relocalised_from ? "relocalised against keyframe " + std::to_string(r.relocalised_from->from_id)
      : r.keyframe_reset ? std::string("a new keyframe at the last pose before it (none validated)")
                         : fmt::format("odometry against keyframe {}, as before the kill",
                                       r.odometry ? r.odometry->from_id : r.keyframe_id);
  spdlog::info("first pose after the restart: frame {}, {}", r.frame_id, how);
}

bool TrackingWorker::trackLocked(const rekon_msgs::frame_t& msg) {
  Intrinsics k;
  std::optional<RgbdFrame> frame = receiver_.receive(msg, &k);
  if (!frame) {
    ++totals_.undecodable;
    return false;
  }
  checkCamera(k);
  const double t0 = threadCpuMs();
  const auto w0 = std::chrono::steady_clock::now();
  const TrackResult r = tracker_.track(*frame, k);
  totals_.frame_ms.emplace_back(
      r.frame_id, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - w0).count());
  totals_.track_cpu_s += 1e-3 * (threadCpuMs() - t0);
  ++totals_.frames;
  totals_.lost += r.state == TrackingState::Lost;
  totals_.keyframes += r.new_keyframe;
  totals_.constraints += r.odometry.has_value();
  totals_.relocalisations += r.relocalised_from.has_value() && !r.reanchored;
  totals_.reanchored += r.reanchored;
  totals_.keyframes_reused += r.keyframe_reused;
  totals_.keyframe_reuse_checks = tracker_.keyframeReuseChecks();
  if (session_.localise_only && r.state == TrackingState::Ok) totals_.localised.push_back({r.timestamp, r.pose_world});
  totals_.odometry.push_back({r.timestamp, r.pose_world});
  totals_.lost_intervals.add(r);
  if (r.state == TrackingState::Lost) spdlog::warn("frame {}: lost ({})", r.frame_id, toString(r.lost_reason));
  keepInSession(r, k);
  if (resuming_ && r.state == TrackingState::Ok) noteFirstPoseAfterRestart(r);
  // Archived before it is published; from then on the cache reads it back from there when it leaves memory.
  if (state_ && r.new_keyframe && !session_.localise_only && state_->archive(*tracker_.currentKeyframe(), r.odometry, k))
    keyframes_->noteArchived(r.keyframe_id, state_->archiveRoot());
  if (session_.localise_only) {
    // Poses only: no back end runs, and the edges name the session's keyframes, never announced on the bus.
    TrackResult poses = r;
    poses.odometry.reset();
    poses.relocalised_from.reset();
    history_.publishResult(poses);
    return true;
  }
  history_.publishResult(r);
  if (r.new_keyframe) loops_.submit(tracker_.currentKeyframe(), r.odometry);
  return true;
}

TrackingCounts TrackingWorker::counts() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return totals_;
}

TrackingTotals TrackingWorker::totals() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return totals_;
}

}  // namespace rekon::tracker
