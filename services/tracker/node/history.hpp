#pragma once
// Everything the tracker has published that a consumer may need again, and
// the publishing itself: a restarted optimiser rebuilds its graph from a
// replay of it, and a frame the player sends again (for a restarted mapper)
// gets its stored result instead of being tracked twice. Written by the bus
// thread and the loop-closure worker; replays go out from the main thread.
// With a journal, constraints and tracked frames are kept as their places in
// it and read back when sent again (PublishedLog), so what the History holds
// per frame is 32 bytes, not the message's 384 plus a map node; keyframes
// (88 bytes, one per 20 frames or more) stay in memory.
#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <mutex>
#include <vector>

#include "published_log.hpp"
#include "rekon/common/bus.hpp"
#include "rekon/common/record_journal.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/tracker.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/replay_request_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::tracker {

// What a killed instance's journal held, beyond what restore() put back into the History.
struct RestoredJournal {
  struct KeyframeEntry {
    rekon_msgs::keyframe_t keyframe;
    std::optional<OdometryConstraint> incoming;  // its odometry edge from its predecessor, when it has one
  };
  std::vector<KeyframeEntry> keyframes;  // in publication order
  int64_t constraints = 0, tracked_frames = 0;
  int64_t last_frame_id = -1;          // the newest tracked frame
  std::optional<Pose> last_pose_world;  // ...its world pose by odometry
  std::optional<OdometryState> odometry_state;  // ...when it was tracked: where odometry stood
  std::optional<rekon_msgs::done_t> done;  // the killed instance had finished the stream
  std::set<int64_t> loop_checked;          // keyframes whose loop-closure check was settled
  Trajectory odometry;                     // the tracked frames' world poses by odometry, in order
};

class History {
 public:
  // `journal`: where each message goes, in order, before it is published
  // (null: none).
  explicit History(Bus& bus, RecordJournal* journal = nullptr) : bus_(bus), journal_(journal) {}

  // A restarted tracker: the killed instance's journal put back, so that
  // replays and frames sent again are answered as before. An undecodable
  // record ends what is taken (one log line).
  RestoredJournal restore(const JournalRead& journal);
  // Whether a record of the tracker's journal decodes as its tag says (RecordJournal's `accept`).
  static bool readable(const JournalRecord& record);
  // A keyframe the killed instance archived but never published, published
  // now (journaled first), with its odometry edge when it has one.
  void publishArchived(const rekon_msgs::keyframe_t& keyframe, const std::optional<OdometryConstraint>& incoming);

  // A tracked frame's new keyframe and its odometry constraint (or the loop
  // edge that relocalised it), then the tracked frame itself: a consumer
  // meeting a new keyframe id in a tracked frame already knows the keyframe.
  void publishResult(const TrackResult& r);
  // An accepted loop closure, from the loop-closure worker.
  void publishLoopConstraint(const LoopConstraint& l);
  // Keyframe `id`'s loop-closure check is settled (LoopClosureWorker::onSettled):
  // journaled only, so that a restart checks again the keyframes whose check
  // the kill cut short.
  void noteLoopChecked(int64_t id);
  // A frame sent again (the player rewinds for a restarted mapper): its
  // stored result goes out again on the live channels, keyframe first as
  // before, when the mapper has restarted since it went out. The optimiser
  // ignores what it already has. False when the frame was never tracked (it
  // was lost on its first way): tracking it now, out of order, would corrupt
  // the odometry.
  bool republishResult(int64_t frame_id);

  // Replay requests wait for serveReplays(), called from the main thread.
  void addReplayRequest(const rekon_msgs::replay_request_t& request);
  // Answers the waiting replay requests, each with one batch from its cursor
  // (messages/recovery.lcm) on the *_RESENT channels and a replay_end_t with
  // the next cursor and the totals.
  void serveReplays();

  // What a replay_end_t reports besides the totals: the newest graph version
  // seen (a restarted optimiser numbers its updates past it) and whether the
  // tracker has finished.
  void noteGraphVersion(int64_t version);
  // Replays say done from now on; `done`, the message that says it, is
  // journaled (a restart after it says done again).
  void markDone(const std::optional<rekon_msgs::done_t>& done = std::nullopt);
  // A mapper process seen on the bus (its resume point, or its heartbeat
  // once running). A pid not seen before, after the first, is a restarted
  // mapper: a newer instance. A frame sent again goes out again only to a
  // newer instance, so that one re-sent for a lost acknowledgement is not
  // fused twice. True when `pid` is a new instance after the first.
  bool noteMapperPid(int pid);

 private:
  void serveBatch(const rekon_msgs::replay_request_t& request);
  // Under mutex_: keyframe `keyframe_id`'s keyframe_t again, once per mapper
  // instance that has not heard it. A mapper restarted after a keyframe was
  // made never placed it (a live source sends none of its frames again), and
  // skipped the frames tracked against it until a graph update placed it.
  void announceAgain(int64_t keyframe_id);
  // Under mutex_: into the journal (when there is one); where it went there.
  template <class M>
  std::optional<uint64_t> journal(RecordTag tag, const M& m) {
    return journal_ ? journal_->append(tag, m) : std::nullopt;
  }
  // Under mutex_: a tracked frame published (or restored), `offset` where the journal holds it.
  void noteTrackedFrame(const rekon_msgs::tracked_frame_t& tf, std::optional<uint64_t> offset);

  // A tracked frame: its message in tracked_log_, and the mapper instance its result went out to.
  struct FrameEntry {
    int64_t frame_id;
    uint32_t index;
    int32_t published_for;
  };
  // Under mutex_: the first of frames_ with an id at or after `frame_id`.
  std::vector<FrameEntry>::iterator firstFrameFrom(int64_t frame_id);
  Bus& bus_;
  RecordJournal* journal_;
  std::mutex mutex_;
  std::vector<rekon_msgs::keyframe_t> keyframes_;
  PublishedLog<rekon_msgs::constraint_t> constraints_{journal_};  // odometry and loop edges, in publication order
  PublishedLog<rekon_msgs::tracked_frame_t> tracked_log_{journal_};
  std::vector<FrameEntry> frames_;  // by frame id
  std::map<int64_t, rekon_msgs::keyframe_t> keyframe_of_frame_;
  int mapper_instance_ = 1;
  std::set<int> mapper_pids_;
  std::map<int64_t, int> announced_for_;  // the mapper instance each keyframe's keyframe_t went out to
  int64_t graph_version_ = -1;
  bool done_ = false;
  std::vector<rekon_msgs::replay_request_t> requests_;  // waiting for the main thread
};

}  // namespace rekon::tracker
