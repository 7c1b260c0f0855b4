#include "tracker_state.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <utility>
#include <vector>

#include "inbox.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/tracker/keyframe_archive.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "tracking_worker.hpp"

namespace rekon::tracker {
namespace fs = std::filesystem;
namespace {

// Ids of the keyframe files in ROOT/tracker/ (dvo_NNNNNN.rkd; a *.tmp a kill left is none).
std::set<int64_t> archivedIds(const std::string& root) {
  std::set<int64_t> ids;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(fs::path(root) / "tracker", ec)) {
    const std::string name = e.path().filename().string();
    long long id = -1;
    char rest[8] = {};
    if (std::sscanf(name.c_str(), "dvo_%lld%7s", &id, rest) == 2 && std::string(rest) == ".rkd" && id >= 0) ids.insert(id);
  }
  return ids;
}

}  // namespace

TrackerState::TrackerState(const std::string& out_dir, bool restarted) {
  if (out_dir.empty()) {
    if (restarted) spdlog::warn("tracker.restarted without an output folder: nothing was kept, tracking starts afresh");
    return;
  }
  root_ = (fs::path(out_dir) / kStateFolder).string();
  const fs::path failed = fs::path(root_) / kFailedFile;
  std::error_code ec;
  if (!restarted) {
    fs::remove_all(fs::path(root_) / "tracker", ec);  // an earlier run's, in the same folder
    fs::remove(failed, ec);
  } else if (fs::exists(failed)) {
    std::ifstream in(failed);
    std::string why;
    std::getline(in, why);
    throw Error(why + " (the killed tracker had stopped on this, " + failed.string() + "; a restart does not go on past it)");
  }
  journal_ = std::make_unique<RecordJournal>((fs::path(root_) / kJournalFile).string(), restarted, History::readable);
  archiving_ = true;
}

bool TrackerState::archive(const Keyframe& keyframe, const std::optional<OdometryConstraint>& incoming,
                           const Intrinsics& camera) {
  if (!archiving_) return false;
  const auto t0 = std::chrono::steady_clock::now();
  try {
    saveKeyframe(root_, keyframe, incoming, camera);
    ++archived_;
  } catch (const Error& e) {
    spdlog::error("{}; no more keyframes are archived: a restart of this tracker relocalises against fewer", e.what());
    archiving_ = false;
  }
  archive_ms_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return archiving_;
}

void TrackerState::markFailed(const std::string& why) {
  if (root_.empty()) return;
  std::error_code ec;
  fs::create_directories(root_, ec);
  std::ofstream((fs::path(root_) / kFailedFile).string()) << why << '\n';
}

void TrackerState::removeArchive() {
  if (root_.empty()) return;
  std::error_code ec;
  const auto removed = fs::remove_all(fs::path(root_) / "tracker", ec);
  if (ec) spdlog::warn("cannot remove the keyframe archive {}/tracker ({})", root_, ec.message());
  else if (removed > 0) spdlog::debug("removed the keyframe archive {}/tracker: the run is over", root_);
}

namespace {

// Odometry goes on against the keyframe the killed instance tracked its last
// frame against; when that frame was lost or its keyframe cannot be read,
// the first frame is relocalised near the last pose instead.
void resumeTracking(const RestoredJournal& restored, const std::string& root, const AlignerParams& aligner,
                    TrackingWorker& worker) {
  if (const auto& state = restored.odometry_state) {
    try {
      worker.resumeOdometry(loadKeyframe(root, state->keyframe_id, aligner).keyframe, *state);
      return;
    } catch (const Error& e) {
      spdlog::warn("{}; the first frame is relocalised near the last pose instead", e.what());
    }
  }
  if (restored.last_pose_world) worker.resumeAt(*restored.last_pose_world);
}

}  // namespace

rekon_msgs::resume_point_t restoreAfterRestart(ServiceContext& ctx, TrackerState& state, History& history,
                                               KeyframeCache& cache, TrackingWorker& worker, LoopClosureWorker& loops,
                                               Inbox& inbox, const AlignerParams& aligner) {
  rekon_msgs::resume_point_t resume{};
  resume.service = ctx.name();
  resume.pid = static_cast<int32_t>(getpid());
  resume.first_missing_frame = -1;
  if (!state.kept()) return resume;
  const RestoredJournal restored = history.restore(state.journal()->contents());
  state.journal()->forgetContents();
  const std::string& root = state.archiveRoot();
  std::set<int64_t> archived = archivedIds(root);
  int64_t highest = -1, missing = 0;
  // Published keyframes whose loop check the kill cut short (or never began): checked again.
  std::vector<std::pair<int64_t, std::optional<OdometryConstraint>>> recheck;
  const auto index = [&](int64_t id, const Pose& pose, const std::optional<OdometryConstraint>& incoming) {
    highest = std::max(highest, id);
    if (!archived.count(id)) {
      ++missing;
      return;
    }
    cache.addArchived(id, pose, root);
    worker.addIndexedKeyframe(id, pose, incoming);
    if (restored.loop_checked.count(id)) loops.addIndexed(id, pose, incoming);
    else recheck.emplace_back(id, incoming);
  };
  for (const auto& entry : restored.keyframes) {
    const std::optional<Pose> pose = fromMsg(entry.keyframe.pose_world);
    if (pose) index(entry.keyframe.keyframe_id, *pose, entry.incoming);
  }
  for (const auto& [id, incoming] : recheck) {
    try {
      loops.submit(loadKeyframe(root, id, aligner).keyframe, incoming);
    } catch (const Error& e) {
      spdlog::error("{}; keyframe {}'s loop check is not made again", e.what(), id);
    }
  }
  if (missing > 0)
    spdlog::warn("{}: {} of the {} journaled keyframes have no archive file; they are not relocalisation or loop "
                 "candidates",
                 root, missing, restored.keyframes.size());
  // Archived, never published (killed in between): published now, so that nothing waits for them.
  int64_t published_now = 0;
  for (const int64_t id : archived) {
    if (id <= highest) continue;
    StoredKeyframe stored;
    try {
      stored = loadKeyframe(root, id, aligner);
    } catch (const Error& e) {
      spdlog::error("{}; keyframe {} is left out", e.what(), id);
      continue;
    }
    rekon_msgs::keyframe_t kf{};
    kf.keyframe_id = id;
    kf.frame_id = stored.keyframe->frame_id;
    kf.timestamp = stored.keyframe->timestamp;
    kf.pose_world = toMsg(stored.keyframe->pose_world);
    history.publishArchived(kf, stored.incoming);
    ++published_now;
    highest = std::max(highest, id);
    cache.addArchived(id, stored.keyframe->pose_world, root);
    worker.addIndexedKeyframe(id, stored.keyframe->pose_world, stored.incoming);
    loops.submit(stored.keyframe, stored.incoming);  // published now: checked now
  }
  worker.continueIdsFrom(highest + 1);
  worker.restoreOdometry(restored.odometry);
  resumeTracking(restored, root, aligner, worker);
  resume.first_missing_frame = restored.last_frame_id < 0 ? -1 : restored.last_frame_id + 1;
  // Its heartbeats say the journal's newest frame, not -1: a player restarted
  // after this restart goes on after it (from -1 it sent every frame again to
  // a tracker that had finished, and waited 60 s for an acknowledgement).
  ctx.setLastFrame(restored.last_frame_id);
  const double rewind_wait_s = ctx.config().getDouble("tracker.rewind_wait_s");
  if (rewind_wait_s < 0) throw Error("tracker.rewind_wait_s must be 0 or more seconds");
  inbox.resumeFrom(resume.first_missing_frame, rewind_wait_s * ctx.config().getDouble("lifecycle.load_factor"));
  if (restored.done) inbox.endAt(restored.done->last_frame_id);
  spdlog::info("restarted: the journal holds {} keyframes, {} constraints and {} tracked frames (the last frame {}){}; "
               "{} keyframes archived ({} published now, {} loop checks made again); new keyframe ids from {}; frames "
               "resume at {}",
               restored.keyframes.size(), restored.constraints, restored.tracked_frames, restored.last_frame_id,
               restored.done ? ", and its done" : "", archived.size(), published_now, recheck.size(), highest + 1,
               resume.first_missing_frame);
  return resume;
}

}  // namespace rekon::tracker
