#pragma once
// An append-only journal of LCM-encoded messages, the form in which a
// service keeps what it has published or heard so that a restarted instance
// rebuilds from it (the tracker's <out>/tracker_state/journal.rkj). A file is
// an 8-byte magic, then records one after another:
//
//   u32 tag   u32 size   size bytes (the message's LCM encoding)   u32 FNV-1a 32 of tag, size and bytes
//
// in the host's byte order (a journal is read on the machine that wrote it).
// One format for every service that journals (the tracker's
// OUT/tracker_state/journal.rkj, the optimiser's OUT/optimiser_journal.rkj).
// Each record goes to the kernel in one write() as it is appended, so a
// killed process loses nothing it appended; there is no fsync (a power cut
// may lose the tail, which reads as a torn record). A record cut short by a
// kill, or one whose checksum does not match, ends what is read: it and
// everything after it are cut off, said in one log line; so is a record the
// reader's `accept` refuses (one that does not decode as its tag says).
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace rekon {

// The tags of the records, one per message type, the same in every journal
// (kLoopCheckedRecord: the tracker's note that a keyframe's loop check was
// settled, a keyframe_t with its id; kGraphVersionRecord: the optimiser's
// note of a graph update it is about to publish, a graph_update_t with only
// its version, or whole for the final one).
enum RecordTag : uint32_t {
  kKeyframeRecord = 1,
  kConstraintRecord = 2,
  kTrackedFrameRecord = 3,
  kDoneRecord = 4,
  kLoopCheckedRecord = 5,
  kGraphVersionRecord = 6,
};

struct JournalRecord {
  uint32_t tag = 0;
  std::string bytes;    // the LCM encoding
  uint64_t offset = 0;  // where it starts in the file (RecordJournal::readAt reads it back from there)
};

struct JournalRead {
  std::vector<JournalRecord> records;  // in append order
  uint64_t valid_bytes = 0;            // of the file, up to the end of the last good record
  bool torn = false;                   // something after valid_bytes was cut off
};

// Whether a record is what its tag says (it decodes); the first refused one ends what is read.
using AcceptRecord = std::function<bool(const JournalRecord&)>;

// What the journal at `path` holds (no records when there is no file).
// rekon::Error naming the file when it is not a journal (wrong magic) or
// cannot be read.
JournalRead readRecordJournal(const std::string& path, const AcceptRecord& accept = nullptr);

// The same read without holding the records: `visit` gets each good record
// in append order (its bytes may be moved out) and returns false to refuse
// it, which ends the read as a bad record does. One record in memory at a time.
struct JournalScan {
  uint64_t valid_bytes = 0;  // as JournalRead's
  bool torn = false;
  size_t records = 0;        // visited and taken
};
JournalScan scanRecordJournal(const std::string& path, const std::function<bool(JournalRecord&)>& visit);

// Decodes a record as message type M; nullopt when it does not decode whole.
template <class M>
std::optional<M> decodeRecord(const JournalRecord& r) {
  M m;
  const int n = m.decode(r.bytes.data(), 0, static_cast<int>(r.bytes.size()));
  if (n != static_cast<int>(r.bytes.size())) return std::nullopt;
  return m;
}

class RecordJournal {
 public:
  // `restarted`: an earlier instance's journal at `path` is read (contents())
  // and appended to after its last good record; else the file is started
  // empty. rekon::Error naming the file when it cannot be written.
  RecordJournal(const std::string& path, bool restarted, const AcceptRecord& accept = nullptr);
  ~RecordJournal();
  RecordJournal(const RecordJournal&) = delete;
  RecordJournal& operator=(const RecordJournal&) = delete;

  const JournalRead& contents() const { return contents_; }
  // Frees what contents() holds once the caller has taken it.
  void forgetContents() { contents_ = JournalRead{}; }
  const std::string& path() const { return path_; }

  // Appends one record; returns where it starts in the file (nullopt when
  // the journal has stopped). A failed write logs one error and stops the
  // journal (the run goes on; a restart then rebuilds less). Not thread-safe.
  std::optional<uint64_t> append(uint32_t tag, const std::string& bytes);
  template <class M>
  std::optional<uint64_t> append(uint32_t tag, const M& message) {
    std::string bytes(static_cast<size_t>(message.getEncodedSize()), '\0');
    message.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
    return append(tag, bytes);
  }
  bool open() const { return fd_ >= 0; }
  // The record that starts at `offset` (an append's result, or a record
  // of contents()), read back from the file; nullopt, with one log line,
  // when it cannot be read whole or its checksum does not match. Safe from
  // any thread (appends only ever add after it).
  std::optional<JournalRecord> readAt(uint64_t offset) const;
  // What this instance appended: records, bytes (framing included) and the
  // wall time its appends took.
  struct Appended {
    int64_t records = 0, bytes = 0;
    double seconds = 0.0;
  };
  const Appended& appended() const { return appended_; }

 private:
  std::string path_;
  int fd_ = -1;
  int read_fd_ = -1;     // for readAt; stays open when a failed write stops the journal
  uint64_t end_ = 0;     // the file's length: where the next record starts
  JournalRead contents_;
  std::string buffer_;  // one record, reused
  Appended appended_;
};

}  // namespace rekon
