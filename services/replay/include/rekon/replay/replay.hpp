#pragma once
// rekon-replay: a second frontend in place of the tracker and the optimiser.
// For every frame the player announces it publishes the pose a given
// trajectory file has for it (say the scene generator's
// drifted_trajectory.txt, or another SLAM system's TUM output) as a tracked
// frame relative to DVO-style keyframes, and graph updates that move those
// keyframes gradually toward a second trajectory (say the ground truth):
// during the stream up to `stream_alpha`, after the end of the stream in
// `final_updates` steps to the target, then done_t as the optimiser does.
// The mapper cannot tell it from the tracker and the optimiser.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/pose.hpp"

namespace rekon::replay {

struct ReplayParams {
  static constexpr double kDefaultKeyframeTranslation = 0.1;  // metres, as the tracker's distance limits
  static constexpr double kDefaultKeyframeRotationDeg = 10.0;
  static constexpr int kDefaultUpdateEveryKeyframes = 3;
  static constexpr double kDefaultStreamAlpha = 0.5;
  static constexpr int kDefaultFinalUpdates = 4;
  static constexpr double kDefaultMaxTimeDifference = 0.02;   // seconds, frame timestamp to trajectory entry

  std::string trajectory;  // poses published as tracked frames
  std::string target;      // poses the graph updates move the keyframes to
  double keyframe_translation = kDefaultKeyframeTranslation;
  double keyframe_rotation_deg = kDefaultKeyframeRotationDeg;
  int update_every_keyframes = kDefaultUpdateEveryKeyframes;  // 0 = no updates during the stream
  double stream_alpha = kDefaultStreamAlpha;  // fraction of the way to the target by the last frame
  int final_updates = kDefaultFinalUpdates;   // steps to the target after the end of the stream (>= 1)
  double max_time_difference = kDefaultMaxTimeDifference;

  void validate() const;
};

// The pose at fraction alpha from a to b (slerp of rotation, lerp of translation).
Pose interpolatePose(const Pose& a, const Pose& b, double alpha);

struct ReplayTracked {
  int64_t frame_id = 0;
  double timestamp = 0.0;
  int64_t keyframe_id = -1;
  Pose pose_in_keyframe = Pose::Identity();
  bool lost = false;
  // Set when this frame starts a DVO keyframe: its world pose as published.
  std::optional<Pose> new_keyframe_world;
};

struct ReplayGraphUpdate {
  int64_t version = 0;
  bool final_update = false;
  std::vector<std::pair<int64_t, Pose>> poses;
};

// The script, free of the bus: the service and the tests drive it.
class ReplayScript {
 public:
  // total_frames: how many frames the stream has (for the update fractions).
  ReplayScript(Trajectory source, Trajectory target, const ReplayParams& params, int64_t total_frames);

  // The tracked frame for a frame, and a graph update when one is due.
  ReplayTracked onFrame(int64_t frame_id, double timestamp);
  std::optional<ReplayGraphUpdate> dueUpdate();
  // The updates after the stream, the last one final and at the target.
  std::vector<ReplayGraphUpdate> finalUpdates();

  // World pose of every keyframe at fraction alpha (for tests).
  ReplayGraphUpdate updateAt(double alpha, bool final_update);

 private:
  struct Keyframe {
    int64_t id;
    Pose source, target;
  };
  Trajectory source_, target_;
  ReplayParams params_;
  int64_t total_frames_;
  int64_t frames_seen_ = 0;
  std::vector<Keyframe> keyframes_;
  int keyframes_since_update_ = 0;
  bool update_due_ = false;
  int64_t version_ = 0;
};

}  // namespace rekon::replay
