#pragma once
// The messages of one kind the tracker has published, in order, for the
// History to send again: with a journal, each is only its offset there
// (16 bytes with its tag, read back when asked for), else the message
// itself. An hour at 30 Hz publishes 108,000 tracked frames (384 bytes each)
// and some 60,000 constraints (368 bytes): 63 MB held, 2.7 MB of offsets.
#include <cstdint>
#include <optional>
#include <vector>

#include "rekon/common/record_journal.hpp"

namespace rekon::tracker {

template <class M>
class PublishedLog {
 public:
  // `journal` null: every message is held.
  explicit PublishedLog(const RecordJournal* journal) : journal_(journal) {}

  // `offset`: where the journal holds `m` (nullopt: it does not, so it is held).
  void add(const M& m, std::optional<uint64_t> offset) {
    if (journal_ && offset) {
      entries_.push_back({*offset, false});
    } else {
      entries_.push_back({held_.size(), true});
      held_.push_back(m);
    }
  }
  // Replaces message i (the same frame tracked again after a restart).
  void replace(size_t i, const M& m, std::optional<uint64_t> offset) {
    if (entries_[i].held) {
      held_[entries_[i].where] = m;
    } else if (offset) {
      entries_[i].where = *offset;
    } else {
      entries_[i] = {held_.size(), true};
      held_.push_back(m);
    }
  }
  size_t size() const { return entries_.size(); }
  // Message i; nullopt when the journal cannot give it back (logged there).
  std::optional<M> at(size_t i) const {
    const Entry& e = entries_[i];
    if (e.held) return held_[e.where];
    const std::optional<JournalRecord> record = journal_->readAt(e.where);
    return record ? decodeRecord<M>(*record) : std::nullopt;
  }

 private:
  struct Entry {
    uint64_t where;  // the journal offset, or the index in held_
    bool held;
  };
  const RecordJournal* journal_;
  std::vector<Entry> entries_;
  std::vector<M> held_;
};

}  // namespace rekon::tracker
