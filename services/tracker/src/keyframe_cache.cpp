#include "rekon/tracker/keyframe_cache.hpp"

#include <signal.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <filesystem>
#include <vector>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"
#include "rekon/tracker/keyframe_archive.hpp"

namespace rekon::tracker {
namespace fs = std::filesystem;
namespace {

int64_t residentBytes(const Keyframe& kf) {
  int64_t bytes = 0;
  for (int l = kf.pyramid.finestLevel(); l <= kf.pyramid.coarsestLevel(); ++l) {
    const PyramidLevel& level = kf.pyramid.level(l);
    bytes += static_cast<int64_t>(sizeof(float) * (level.intensity.size() + level.depth.size()));
  }
  for (int l = kf.reference.finestLevel(); l <= kf.reference.coarsestLevel(); ++l) {
    const KeyframeReference::Level& level = kf.reference.level(l);
    bytes += static_cast<int64_t>(sizeof(float) * (level.points.size() + level.jacobians.size()));
  }
  return bytes;
}

// Automatic spill folders of trackers that died without removing theirs
// (killed, crashed): rekon_tracker_<pid>.spill whose pid no longer runs.
void removeStaleSpillFolders(const fs::path& tmp) {
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(tmp, ec)) {
    const std::string name = entry.path().filename().string();
    int pid = 0;
    char rest[8] = {};
    if (std::sscanf(name.c_str(), "rekon_tracker_%d%7s", &pid, rest) != 2 || std::string(rest) != ".spill") continue;
    if (pid <= 0 || pid == getpid() || kill(pid, 0) == 0 || errno != ESRCH) continue;
    std::error_code removed;
    if (fs::remove_all(entry.path(), removed) > 0 && !removed)
      spdlog::info("removed {}, the keyframe spill folder of a tracker that is gone", entry.path().string());
  }
}

}  // namespace

KeyframeCache::KeyframeCache(const TrackerParams& params)
    : aligner_(params.aligner), in_memory_(params.memory.keyframes_in_memory), spill_setting_(params.memory.spill_dir) {}

KeyframeCache::~KeyframeCache() {
  if (spill_root_.empty()) return;
  std::error_code ec;
  for (const auto& [id, slot] : slots_)
    if (slot.on_disk && slot.archive.empty()) fs::remove(keyframeFile(spill_root_, id), ec);
  fs::remove(fs::path(spill_root_) / "tracker", ec);  // only when empty: a shared folder keeps others' files
  if (made_root_) fs::remove(spill_root_, ec);
}

std::string KeyframeCache::spillRoot() {
  if (!spill_root_.empty()) return spill_root_;
  if (spill_setting_ == KeyframeMemoryParams::kAutoSpillDir) {
    const fs::path root = tempFolder();
    removeStaleSpillFolders(root);
    spill_root_ = (root / ("rekon_tracker_" + std::to_string(getpid()) + ".spill")).string();
  } else {
    spill_root_ = fs::absolute(spill_setting_).string();
  }
  std::error_code ec;
  made_root_ = fs::create_directories(spill_root_, ec);
  if (ec)
    throw Error("cannot create the tracker's keyframe spill folder " + spill_root_ + " (" + ec.message() +
                "); set tracker.keyframe_spill_dir to a writable folder");
  spdlog::info("tracker: DVO keyframes beyond {} in memory go to {}", in_memory_, spill_root_);
  return spill_root_;
}

void KeyframeCache::add(std::shared_ptr<const Keyframe> keyframe) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto [it, added] = slots_.try_emplace(keyframe->id);
  if (!added) return;
  it->second.pose_world = keyframe->pose_world;
  stats_.resident_bytes += residentBytes(*keyframe);
  it->second.resident = std::move(keyframe);
  ++stats_.keyframes;
  ++stats_.resident;
  stats_.resident_peak = std::max(stats_.resident_peak, stats_.resident);
  shrinkAround(it->second.pose_world.translation());
}

void KeyframeCache::addArchived(int64_t id, const Pose& pose_world, const std::string& root) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto [it, added] = slots_.try_emplace(id);
  if (!added) return;
  it->second.pose_world = pose_world;
  it->second.on_disk = true;
  it->second.archive = root;
  ++stats_.keyframes;
}

void KeyframeCache::noteArchived(int64_t id, const std::string& root) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = slots_.find(id);
  if (it == slots_.end() || it->second.on_disk) return;
  it->second.on_disk = true;
  it->second.archive = root;
}

std::shared_ptr<const Keyframe> KeyframeCache::get(int64_t id) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = slots_.find(id);
  if (it == slots_.end()) return nullptr;
  if (it->second.resident) return it->second.resident;
  const std::string& root = it->second.archive.empty() ? spill_root_ : it->second.archive;
  std::shared_ptr<const Keyframe> kf = loadKeyframe(root, id, aligner_).keyframe;
  ++stats_.loaded;
  ++stats_.resident;
  stats_.resident_bytes += residentBytes(*kf);
  it->second.resident = kf;
  // The newest keyframe marks the camera; the one just read stays with the caller for its check.
  shrinkAround(slots_.rbegin()->second.pose_world.translation());
  return kf;
}

void KeyframeCache::shrinkAround(const Eigen::Vector3d& near) {
  if (in_memory_ <= 0 || stats_.resident <= in_memory_) return;
  std::vector<std::pair<double, int64_t>> by_distance;  // farthest first; equal: oldest first
  for (const auto& [id, slot] : slots_)
    if (slot.resident) by_distance.emplace_back(-(slot.pose_world.translation() - near).norm(), id);
  std::sort(by_distance.begin(), by_distance.end());
  for (const auto& [minus_distance, id] : by_distance) {
    if (stats_.resident <= in_memory_) break;
    Slot& slot = slots_.at(id);
    if (!slot.on_disk) {
      saveKeyframe(spillRoot(), *slot.resident, std::nullopt, slot.resident->pyramid.camera());
      slot.on_disk = true;
      ++stats_.spilled;
    }
    stats_.resident_bytes -= residentBytes(*slot.resident);
    slot.resident.reset();
    --stats_.resident;
  }
}

KeyframeCacheStats KeyframeCache::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

}  // namespace rekon::tracker
