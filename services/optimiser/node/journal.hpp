#pragma once
// The optimiser's journal, <out>/optimiser_journal.rkj: every keyframe,
// constraint and tracked frame as it arrived, appended as the run goes, each
// record going to the kernel as it is appended. Its format is the tracker's
// (rekon/common/record_journal.hpp): each record the LCM message of its kind
// (keyframe_t with id and pose; constraint_t with the information as applied;
// tracked_frame_t with id, time, keyframe, pose and lost as its state;
// graph_update_t: an update about to go out, only its version, or whole for
// the final one), the poses as on the bus. A restarted optimiser rebuilds its
// graph and frames from it and asks the tracker only for what came after
// (recovery.hpp: journalCursor); a first instance starts it empty. A torn or unreadable
// record (a kill in the middle of a write) ends what is read, with a warning,
// and is cut off before the restart appends: what follows is asked for again.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "graph_worker.hpp"
#include "rekon/common/record_journal.hpp"
#include "inbox.hpp"

namespace rekon::optimiser {

inline constexpr const char* kJournalFile = "optimiser_journal.rkj";

struct JournalContents {
  std::vector<GraphItem> items;      // in arrival order
  std::vector<TrackedFrame> frames;  // in arrival order
  int64_t newest_version = 0;        // of the graph updates published (0: none)
  std::optional<rekon_msgs::graph_update_t> final_update;  // the newest final one, whole
  size_t records_read = 0;
};

// What the journal at `path` holds (empty when there is none).
JournalContents readJournal(const std::string& path);

class Journal {
 public:
  // `out_dir` "": no journal. `restarted`: the earlier instance's journal is
  // read (contents()) and appended to; else it is started empty. rekon::Error
  // naming the file when it cannot be written.
  Journal(const std::string& out_dir, bool restarted);
  const JournalContents& contents() const { return contents_; }
  // Frees what contents() holds once the graph is rebuilt from it.
  void forgetContents() { contents_ = JournalContents{}; }
  // Appends; a failed write logs one error and stops the journal (the run
  // goes on; a restart then asks for more).
  void append(const std::vector<GraphItem>& items, const std::vector<TrackedFrame>& frames);
  // Before a graph update goes out: its version, so that a restart numbers
  // its updates after it (consumers ignore versions they have seen, and a
  // restarted tracker, which would say the newest, has seen none); the final
  // update whole, so that a restart after it sends the same poses again.
  void noteUpdate(const rekon_msgs::graph_update_t& update);
  bool enabled() const { return journal_ != nullptr; }
  // Every tracked frame it holds, read back from the file, once each, by id;
  // with the frames a stopped journal could not take (kept here instead).
  std::vector<TrackedFrame> trackedFrames() const;

 private:
  std::unique_ptr<RecordJournal> journal_;
  JournalContents contents_;
  std::vector<TrackedFrame> unwritten_frames_;  // after a failed write
};

// Items the inbox queued, journaled (those the worker has not seen) with the
// tracked frames heard since the last call, then applied to the worker; true
// when an edge was added.
bool applyArrived(const std::vector<GraphItem>& items, Inbox& inbox, GraphWorker& worker, Journal& journal);

}  // namespace rekon::optimiser
