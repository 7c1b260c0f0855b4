#pragma once
// The shared-memory keyframe store (issue 7, section 2): every fused KF
// keyframe (depth, weights, color, anchor DVO keyframe, pose in the anchor,
// the pose it is integrated with) in a named Boost.Interprocess segment owned
// by the mapping service. It outlives a crashed or stopped mapper, so a
// restarted one rebuilds its volume from it, and other processes read it
// (`rekon keyframes`). Capacity is a run-time setting; a full store is an
// error naming the setting to raise.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/fusion/keyframe_fusion.hpp"

namespace rekon::store {

struct StoreOptions {
  static constexpr int kDefaultSizeMb = 1024;
  std::string segment = "rekon_keyframes";
  int size_mb = kDefaultSizeMb;
};

// What `--list` shows of one keyframe (no images).
struct KeyframeInfo {
  int64_t id = -1;
  int64_t anchor_keyframe_id = -1;
  int64_t first_frame_id = -1, last_frame_id = -1;
  int frames = 0;
  double timestamp = 0.0;
  Pose pose_in_anchor = Pose::Identity();
  Pose integrated_pose = Pose::Identity();
  bool integrated = false;
};

class KeyframeStore {
 public:
  // Opens the segment when it exists (its intrinsics must equal k, else
  // rekon::Error), else creates it with options.size_mb MiB.
  static std::unique_ptr<KeyframeStore> openOrCreate(const StoreOptions& options, const Intrinsics& k);
  // Opens an existing segment read-only for another process; rekon::Error when absent.
  static std::unique_ptr<KeyframeStore> openExisting(const std::string& segment);
  // Deletes the named segment (no-op when absent); true when one was removed.
  static bool remove(const std::string& segment);
  ~KeyframeStore();

  const std::string& segment() const;
  Intrinsics intrinsics() const;
  size_t size() const;
  size_t freeBytes() const;
  size_t totalBytes() const;

  // Copies the keyframe into the segment; rekon::Error when it does not fit
  // (naming mapper.store_mb) or when its id is already stored.
  void add(const fusion::FusedKeyframe& kf);
  // Records the pose the keyframe is now integrated with.
  void setIntegratedPose(int64_t id, const Pose& pose);
  // Latest known world pose of a DVO keyframe (so a restart can place frames).
  void setAnchorPose(int64_t keyframe_id, const Pose& pose);
  std::vector<std::pair<int64_t, Pose>> anchorPoses() const;

  std::vector<KeyframeInfo> list() const;
  // The full keyframe (images copied out of the segment) at index i of list().
  fusion::FusedKeyframe load(size_t index) const;

 private:
  struct Impl;
  explicit KeyframeStore(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// `rekon keyframes --list | --export DIR [--segment NAME]`.
int keyframesMain(int argc, char** argv);

}  // namespace rekon::store
