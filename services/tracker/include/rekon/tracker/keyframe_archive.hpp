#pragma once
// The tracker's part of a session (issue 18; services/mapper/src/store/SESSION.md):
// every DVO keyframe, so that a continued run relocalises against them and
// closes loops to them. One file per keyframe, SESSION/tracker/dvo_NNNNNN.rkd,
// renamed into place whole: the camera, the keyframe's ids, time and
// odometry pose, its incoming odometry constraint, its pyramid's finest
// level (float intensity and depth) and an FNV-1a 64 checksum of all of it.
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/tracker.hpp"

namespace rekon::tracker {

struct StoredKeyframe {
  Intrinsics camera;  // of the frames it was made from
  std::shared_ptr<const Keyframe> keyframe;
  std::optional<OdometryConstraint> incoming;  // absent for a first keyframe, after a reset or a relocalisation
};

// Writes `kf` (made from frames of `camera`) into SESSION/tracker/.
// rekon::Error naming the file when it cannot be written.
void saveKeyframe(const std::string& session_dir, const Keyframe& kf, const std::optional<OdometryConstraint>& incoming,
                  const Intrinsics& camera);

// Every keyframe in SESSION/tracker/, id order, with pyramids and references
// rebuilt for `params`. A file left by a killed writer (*.tmp) is not a
// keyframe. rekon::Error, one line naming the file and the fix: none there, a
// damaged file, another camera than the first file's, keyframes stored at a
// coarser level than params.finest_level.
std::vector<StoredKeyframe> loadKeyframes(const std::string& session_dir, const AlignerParams& params);

// SESSION/tracker/'s file of keyframe `id`, and that one keyframe read back
// (rekon::Error as loadKeyframes for a missing or damaged file).
std::string keyframeFile(const std::string& session_dir, int64_t id);
StoredKeyframe loadKeyframe(const std::string& session_dir, int64_t id, const AlignerParams& params);

// SESSION/anchors.txt (written by the mapper; SESSION.md): every DVO
// keyframe's newest world pose, the optimised one once the graph placed it,
// by id. rekon::Error naming the file when it is missing or damaged.
std::unordered_map<int64_t, Pose> loadMapPoses(const std::string& session_dir);

}  // namespace rekon::tracker
