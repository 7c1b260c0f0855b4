#pragma once
// A session on disk (issue 18): what a run leaves so that its map can be
// rebuilt at other settings and exported without the frames. The mapper
// writes it as the run goes (src/store/SESSION.md has the layout and its
// guarantees); `rekon remesh` and `rekon export` read it.
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/mapper/fusion/keyframe_fusion.hpp"

namespace rekon::store {

inline constexpr int kSessionFormatVersion = 1;

// session.yaml: the format, the camera and the volume the map was made with.
struct SessionInfo {
  int format_version = kSessionFormatVersion;
  Intrinsics camera;
  double voxel_size = 0.01, truncation = 0.04, max_depth = 4.0;
};

// One fused frame: its DVO keyframe and its pose in it (frames.txt).
struct SessionFrame {
  int64_t frame_id = -1;
  double timestamp = 0.0;
  int64_t keyframe_id = -1;
  Pose pose_in_keyframe = Pose::Identity();
};

// rekon::Error naming `dir` and the fix when it already holds a session
// (rekon run checks before it starts anything; a new writer checks again).
void requireNoSession(const std::string& dir);

// The mapper's side: every call leaves the folder a session that opens.
class SessionWriter {
 public:
  // Creates `dir` with session.yaml, or with `reopen` (a restarted mapper of
  // the same run) goes on writing one that exists with the same camera.
  // rekon::Error naming the folder and the fix when it holds a session and
  // `reopen` is false, or one of another format or camera.
  SessionWriter(const std::string& dir, const SessionInfo& info, bool reopen);
  ~SessionWriter();
  SessionWriter(const SessionWriter&) = delete;
  SessionWriter& operator=(const SessionWriter&) = delete;

  // The images, then the metadata that makes the keyframe part of the
  // session (each file renamed into place whole); frames.txt is flushed too.
  void addKeyframe(const fusion::FusedKeyframe& kf);
  // True when keyframe `id` is in the session (its metadata is written).
  bool has(int64_t id) const;
  // anchors.txt: the newest world pose of every DVO keyframe (rewritten whole).
  void setAnchorPoses(const std::map<int64_t, Pose>& poses);
  // Appended to frames.txt (buffered; flushed with each keyframe and at exit).
  void addFrame(const SessionFrame& frame);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The readers' side (rekon remesh, rekon export).
class Session {
 public:
  // Checks session.yaml (format version, camera) and lists the keyframes
  // whose metadata and images are both there. rekon::Error, one line naming
  // the file and the fix: no session, a newer format, a damaged file.
  static Session open(const std::string& dir);

  const std::string& dir() const { return dir_; }
  const SessionInfo& info() const { return info_; }
  // Keyframes without images (id order).
  const std::vector<fusion::FusedKeyframe>& keyframes() const { return keyframes_; }
  // The images of keyframes()[i]; rekon::Error naming the file when missing, truncated or corrupt.
  fusion::FusedKeyframe load(size_t i) const;
  const std::map<int64_t, Pose>& anchors() const { return anchors_; }
  // The world pose of a keyframe through its anchor's newest pose; nullopt
  // when the anchor's pose never reached the session (lost in flight).
  std::optional<Pose> worldPose(const fusion::FusedKeyframe& kf) const;
  // frames.txt (a line cut short by a killed writer is left out).
  std::vector<SessionFrame> frames() const;

 private:
  std::string dir_;
  SessionInfo info_;
  std::vector<fusion::FusedKeyframe> keyframes_;
  std::map<int64_t, Pose> anchors_;
};

}  // namespace rekon::store
