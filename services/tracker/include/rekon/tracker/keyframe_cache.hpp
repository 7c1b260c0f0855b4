#pragma once
// The DVO keyframes that loop closure and relocalisation align against, one
// copy shared by both, with at most `in_memory` of them resident (pyramid and
// reference: about 3.3 MB each at 640x480). The others wait on disk in the
// session archive's form (keyframe_archive.hpp: the finest level, 0.6 MB)
// and are rebuilt when a check needs them. When one more is resident than
// allowed, the one farthest from the newest keyframe goes to disk (the
// mapper's keyframe store spills on the same rule): loop and relocalisation
// candidates lie near the camera. Thread-safe.
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "rekon/tracker/params.hpp"
#include "rekon/tracker/tracker.hpp"

namespace rekon::tracker {

struct KeyframeCacheStats {
  int64_t keyframes = 0;
  int64_t resident = 0;
  int64_t resident_peak = 0;
  int64_t spilled = 0;     // files written (a keyframe is written once)
  int64_t loaded = 0;      // read back from disk
  int64_t resident_bytes = 0;
};

class KeyframeCache {
 public:
  // params.memory.keyframes_in_memory 0: every keyframe stays resident (no files).
  explicit KeyframeCache(const TrackerParams& params);
  ~KeyframeCache();  // removes the files it wrote, and the folder it made
  KeyframeCache(const KeyframeCache&) = delete;
  KeyframeCache& operator=(const KeyframeCache&) = delete;

  // Adds a keyframe (again: ignored); may move others to disk. rekon::Error
  // naming the file when one cannot be written (the keyframe stays resident).
  void add(std::shared_ptr<const Keyframe> keyframe);
  // A keyframe already on disk in an archive (ROOT/tracker/dvo_NNNNNN.rkd,
  // keyframe_archive.hpp), indexed without reading it: get() reads it when a
  // check first needs it (a restarted tracker's earlier keyframes). The file
  // is never removed by the cache. Again: ignored.
  void addArchived(int64_t id, const Pose& pose_world, const std::string& root);
  // Keyframe `id`, added before, now also in the archive at `root`: when it
  // leaves memory it is read back from there, never written to the spill
  // folder. Unknown or already on disk: ignored.
  void noteArchived(int64_t id, const std::string& root);
  // The keyframe with its pyramid and reference, read back when on disk;
  // null for an id never added.
  std::shared_ptr<const Keyframe> get(int64_t id);
  KeyframeCacheStats stats() const;

 private:
  struct Slot {
    std::shared_ptr<const Keyframe> resident;  // null while only on disk
    Pose pose_world = Pose::Identity();
    bool on_disk = false;
    std::string archive;  // the archive root it is read from; "": spill_root_ (and removed at exit)
  };
  // Under mutex_: moves the resident keyframes farthest from `near` to disk
  // until at most in_memory_ are resident.
  void shrinkAround(const Eigen::Vector3d& near);
  std::string spillRoot();

  const AlignerParams aligner_;
  const int in_memory_;
  const std::string spill_setting_;
  std::string spill_root_;  // made on the first spill
  bool made_root_ = false;
  mutable std::mutex mutex_;
  std::map<int64_t, Slot> slots_;
  KeyframeCacheStats stats_;
};

}  // namespace rekon::tracker
