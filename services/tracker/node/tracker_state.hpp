#pragma once
// What a killed tracker leaves for its restart (tracker.restarted), written on
// every run under <out>/tracker_state/: journal.rkj, every keyframe,
// constraint, tracked frame and done_t it published, in order
// (RecordJournal, appended before each goes on the bus), and tracker/, its DVO
// keyframes (keyframe_archive.hpp), each written before its keyframe is
// published. A first instance starts both empty.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "history.hpp"
#include "rekon/common/camera.hpp"
#include "rekon/common/record_journal.hpp"
#include "rekon/common/service.hpp"
#include "rekon/tracker/keyframe_cache.hpp"
#include "rekon/tracker/tracker.hpp"
#include "rekon_msgs/resume_point_t.hpp"

namespace rekon::tracker {

inline constexpr const char* kStateFolder = "tracker_state";
inline constexpr const char* kJournalFile = "journal.rkj";
inline constexpr const char* kFailedFile = "failed.txt";

class TrackerState {
 public:
  // `out_dir` "": nothing is kept (a restart then starts afresh, said once).
  // rekon::Error naming the file when the journal cannot be written, and for
  // a restart of a tracker that had stopped on an error (markFailed), that error.
  TrackerState(const std::string& out_dir, bool restarted);
  bool kept() const { return journal_ != nullptr; }
  RecordJournal* journal() { return journal_.get(); }
  // The archive root (its keyframes are ROOT/tracker/dvo_NNNNNN.rkd); "" when none.
  const std::string& archiveRoot() const { return root_; }
  // Writes a new keyframe into the archive; true when it is there. A failed
  // write logs one error and stops the archive (the run goes on; a restart
  // relocalises against fewer).
  bool archive(const Keyframe& keyframe, const std::optional<OdometryConstraint>& incoming, const Intrinsics& camera);
  // The tracker stops on an error it cannot get past (a continued session not
  // relocalised): kept in failed.txt, so that a restart stops on it again at
  // once instead of going on as if it had not happened.
  void markFailed(const std::string& why);
  // The run is over (the tracker ends cleanly, after its consumers): the
  // keyframe archive goes (0.6 MB a keyframe at 640x480); the journal stays.
  void removeArchive();
  int64_t archived() const { return archived_; }
  double archiveMs() const { return archive_ms_; }

 private:
  std::string root_;
  std::unique_ptr<RecordJournal> journal_;
  bool archiving_ = false;
  int64_t archived_ = 0;
  double archive_ms_ = 0.0;
};

class TrackingWorker;
class LoopClosureWorker;
class Inbox;

// The restart itself: the journal into `history`; every keyframe in journal or
// archive indexed (not read) in `cache`, in the tracker's relocaliser and in
// `loops` (not started yet); those archived but never published published;
// ids continued past the highest; the first frame to relocalise near the last
// journaled pose; `inbox` told where the frames resume. Returns the resume
// point to announce.
rekon_msgs::resume_point_t restoreAfterRestart(ServiceContext& ctx, TrackerState& state, History& history,
                                               KeyframeCache& cache, TrackingWorker& worker, LoopClosureWorker& loops,
                                               Inbox& inbox, const AlignerParams& aligner);

}  // namespace rekon::tracker
