#pragma once
// Tracks the frames the bus thread hands it, one at a time and in order,
// publishes each result through the History, and hands each new DVO keyframe
// to the loop-closure worker after its result is out (so that a loop
// constraint never reaches the bus before its keyframe).
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "history.hpp"
#include "tracker_state.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/lost_intervals.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/tracker.hpp"
#include "rekon_msgs/frame_t.hpp"

namespace rekon::tracker {

struct TrackingCounts {
  int64_t restored_frames = 0;  // a restart: tracked by the killed instances (their journal), not in `frames`
  int64_t frames = 0, lost = 0, keyframes = 0, constraints = 0, undecodable = 0, relocalisations = 0;
  int64_t reanchored = 0;  // session.localise_only: due keyframes placed by the map (not in relocalisations)
  int64_t keyframes_reused = 0;  // tracker.keyframe_reuse: due keyframes not made (an existing one reused)
  int64_t keyframe_reuse_checks = 0;  // ...and the existing keyframes aligned to decide
};

struct TrackingTotals : TrackingCounts {
  double track_cpu_s = 0.0;
  std::vector<std::pair<int64_t, double>> frame_ms;  // wall time of track() (pyramid included) per frame
  Trajectory odometry;                               // world poses by odometry alone
  Trajectory localised;                              // session.localise_only: the frames placed in the map
  LostIntervals lost_intervals;
};

// The session (issue 18): where the DVO keyframes are kept, and whether the
// run continues one (session.dir, session.continue, session.relocalise_frames)
// or only localises in it (session.localise_only, issue 28: nothing written
// to the session, its keyframes at their poses in anchors.txt are the map).
struct TrackerSession {
  std::string dir;  // "" = none
  bool continued = false;
  bool localise_only = false;
  int relocalise_frames = 0;
  static TrackerSession fromConfig(const Config& config);
};

class TrackingWorker {
 public:
  // With session.continue the session's keyframes are loaded here: rekon::Error naming the file when one is damaged.
  // `keyframes`: the DVO keyframes' cache, shared with `loops`.
  // `state`: where each new keyframe is archived before it is published (null: nowhere).
  TrackingWorker(const TrackerParams& params, const TrackerSession& session, History& history, LoopClosureWorker& loops,
                 std::shared_ptr<KeyframeCache> keyframes, TrackerState* state = nullptr);

  // A restarted tracker, before the first frame (Tracker's methods of the same names).
  void addIndexedKeyframe(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming);
  void continueIdsFrom(int64_t next_id);
  void resumeAt(const Pose& last_pose_world);
  void resumeOdometry(std::shared_ptr<const Keyframe> keyframe, const OdometryState& state);
  // The killed instances' odometry (their journal), before this one's in odometry.txt.
  void restoreOdometry(const Trajectory& odometry);
  // How the restart's first pose came: "odometry" (against the killed
  // instance's keyframe), "relocalised", "new keyframe" (none validated); ""
  // before it, or when this is no restart.
  std::string resumedBy() const;

  // Decodes and tracks one frame; false when it does not decode (the
  // receiver logged why).
  bool track(const rekon_msgs::frame_t& msg);
  // The optimiser's poses (bus thread).
  void updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses);
  TrackingTotals totals() const;
  TrackingCounts counts() const;  // cheap: no per-frame tables
  // Why the run cannot go on (a continued session not relocalised in time, a
  // session file not written), set once; the service stops with it.
  std::optional<std::string> failure() const;

 private:
  // track() under the lock; rekon::Error for what stops the service.
  bool trackLocked(const rekon_msgs::frame_t& msg);
  void noteFirstPoseAfterRestart(const TrackResult& r);  // resumed_by_ and its log line
  void continueSession(const TrackerParams& params);
  // A continued session's camera must be this run's. Throws rekon::Error.
  void checkCamera(const Intrinsics& k) const;
  // The session's side of a tracked frame: its camera checked against the
  // session's, its new keyframe kept. Throws rekon::Error.
  void keepInSession(const TrackResult& r, const Intrinsics& k);

  TrackerSession session_;
  TrackerState* state_;
  bool resuming_ = false;
  std::string resumed_by_;
  History& history_;
  LoopClosureWorker& loops_;
  std::shared_ptr<KeyframeCache> keyframes_;
  mutable std::mutex mutex_;
  Tracker tracker_;
  FrameReceiver receiver_;
  TrackingTotals totals_;
  std::optional<Intrinsics> session_camera_;  // of the stored keyframes, when continuing
  size_t stored_keyframes_ = 0;
  std::optional<std::string> failure_;
};

}  // namespace rekon::tracker
