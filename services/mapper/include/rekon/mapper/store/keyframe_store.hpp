#pragma once
// The shared-memory keyframe store (issue 7, section 2): every fused KF
// keyframe (depth, weights, color, anchor DVO keyframe, pose in the anchor,
// the pose it is integrated with) in a named Boost.Interprocess segment owned
// by the mapping service. It outlives a crashed or stopped mapper, so a
// restarted one rebuilds its volume from it, and other processes read it
// (`rekon keyframes`).
//
// Capacity policy (issue 9): the segment has a fixed size (store_mb). When a
// new keyframe does not fit, resident keyframes spill to files in the spill
// directory, farthest first from where the camera is now (the new keyframe's
// position through its anchor's pose; ties: oldest first), until it fits. The
// keyframe's metadata stays in the segment, so list() is unchanged and load()
// reads a spilled keyframe back from its file (checked: magic, size,
// checksum), for this process or any other. A store spills a keyframe at most
// once and never brings it back: shared memory holds the newest, nearest
// keyframes, disk the rest. remove() deletes the spill files with the
// segment. With spilling off (spill_dir "off") a full store is an error
// naming mapper.store_mb, as before.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/mapper/fusion/keyframe_fusion.hpp"
#include "rekon/mapper/store/broken_store.hpp"

namespace rekon::store {

struct StoreOptions {
  static constexpr int kDefaultSizeMb = 1024;
  static constexpr const char* kAutoSpillDir = "auto";
  static constexpr const char* kNoSpilling = "off";
  std::string segment = "rekon_keyframes";
  int size_mb = kDefaultSizeMb;
  // Where full-segment keyframes go: "auto" = $TMPDIR (else /tmp)/<segment>.spill,
  // "off" = nowhere (full is an error), else a folder (created; may be shared
  // by several stores: files are named after the segment). "off" here keeps
  // callers that predate spilling as they were; the configuration
  // (mapper.store_spill_dir, read by fromConfig) defaults to "auto".
  std::string spill_dir = kNoSpilling;

  // mapper.store_segment, mapper.store_mb, mapper.store_spill_dir.
  static StoreOptions fromConfig(const Config& config);
};

// The folder "auto" stands for, for a segment.
std::string autoSpillDir(const std::string& segment);

// Where the keyframes are, for stats and `rekon keyframes --list`.
struct StoreUsage {
  size_t keyframes = 0;
  size_t resident = 0;          // images in the segment
  size_t spilled = 0;           // images in spill files
  size_t shm_used_bytes = 0;    // of the segment
  size_t shm_total_bytes = 0;
  size_t spilled_bytes = 0;     // spill files on disk
  std::string spill_dir;        // "" when spilling is off
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
  bool spilled = false;  // its images are in a spill file, not in the segment
};

// The keyframe `info` describes, without its images (KeyframeStore::loadById reads those).
fusion::FusedKeyframe withoutImages(const KeyframeInfo& info);

class KeyframeStore {
 public:
  // Opens the segment when it exists (its intrinsics must equal k, else
  // rekon::Error), else creates it with options.size_mb MiB. The spill folder
  // is created (rekon::Error when it cannot be); an existing segment keeps
  // the folder it was created with, where its spilled keyframes are.
  static std::unique_ptr<KeyframeStore> openOrCreate(const StoreOptions& options, const Intrinsics& k);
  // Opens an existing segment read-only for another process; rekon::Error when absent.
  static std::unique_ptr<KeyframeStore> openExisting(const std::string& segment);
  // Deletes the named segment and its spill files (no-op when absent); true
  // when a segment was removed.
  static bool remove(const std::string& segment);
  ~KeyframeStore();

  const std::string& segment() const;
  Intrinsics intrinsics() const;
  size_t size() const;
  size_t freeBytes() const;
  size_t totalBytes() const;
  StoreUsage usage() const;

  // Copies the keyframe into the segment, spilling others when it is full;
  // rekon::Error when its id is already stored, when it cannot fit (spilling
  // off, or the segment smaller than one keyframe: naming mapper.store_mb) or
  // when a spill file cannot be written (disk full: naming the file). After
  // an error the store holds what it held before.
  void add(const fusion::FusedKeyframe& kf);
  // Records the pose the keyframe is now integrated with.
  void setIntegratedPose(int64_t id, const Pose& pose);
  // Latest known world pose of a DVO keyframe (so a restart can place frames).
  void setAnchorPose(int64_t keyframe_id, const Pose& pose);
  std::vector<std::pair<int64_t, Pose>> anchorPoses() const;
  // The run that filled the store finished: its outputs are written and its
  // end (the stream's last frame) is said. A mapper restarted after this has
  // nothing to redo; it says the end again (runEndFrame) instead.
  void markRunFinished(int64_t end_frame);
  std::optional<int64_t> runEndFrame() const;

  std::vector<KeyframeInfo> list() const;
  // The full keyframe (images copied out of the segment or read from its
  // spill file) at index i of list(); rekon::Error for a spill file that is
  // missing, truncated or corrupt.
  fusion::FusedKeyframe load(size_t index) const;
  // The same by keyframe id; rekon::Error when the id is not stored.
  fusion::FusedKeyframe loadById(int64_t id) const;

 private:
  struct Impl;
  explicit KeyframeStore(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace rekon::store
