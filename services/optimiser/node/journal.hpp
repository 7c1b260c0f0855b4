#pragma once
// The optimiser's journal, <out>/optimiser_journal.txt: every keyframe,
// constraint and tracked frame as it arrived, one line each, appended as the
// run goes and flushed with each batch (doubles written exactly). A restarted
// optimiser rebuilds its graph and frames from it and asks the tracker only
// for what came after (recovery.hpp: journalCursor); a first instance starts
// it empty. A torn or unreadable line (a kill in the middle of a write) ends
// what is read, with a warning: what follows is asked for again.
//
//   K id  m00 m01 m02 m03  m10 .. m13  m20 .. m23           a keyframe (pose: top 3x4 of its matrix)
//   O from to  <3x4 relative>  <36 information>            an odometry edge (information as applied)
//   L from to  <3x4 relative>  <36 information>            a loop edge
//   F frame_id timestamp keyframe_id lost  <3x4 pose in keyframe>
#include <cstdint>
#include <fstream>
#include <string>
#include <vector>

#include "graph_worker.hpp"
#include "inbox.hpp"

namespace rekon::optimiser {

inline constexpr const char* kJournalFile = "optimiser_journal.txt";

struct JournalContents {
  std::vector<GraphItem> items;      // in arrival order
  std::vector<TrackedFrame> frames;  // in arrival order
  size_t lines_read = 0;
  size_t bytes_read = 0;  // of those lines, newlines included
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
  // Appends and flushes; a failed write logs one error and stops the journal
  // (the run goes on; a restart then asks for more).
  void append(const std::vector<GraphItem>& items, const std::vector<TrackedFrame>& frames);

 private:
  std::string path_;
  std::ofstream out_;
  JournalContents contents_;
};

// Items the inbox queued, journaled (those the worker has not seen) with the
// tracked frames heard since the last call, then applied to the worker; true
// when an edge was added.
bool applyArrived(const std::vector<GraphItem>& items, Inbox& inbox, GraphWorker& worker, Journal& journal);

}  // namespace rekon::optimiser
