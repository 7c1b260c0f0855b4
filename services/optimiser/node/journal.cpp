#include "journal.hpp"

#include <algorithm>
#include <filesystem>
#include <map>
#include <variant>

#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::optimiser {
namespace {

rekon_msgs::keyframe_t keyframeMsg(const KeyframeIn& kf) {
  rekon_msgs::keyframe_t m{};
  m.keyframe_id = kf.id;
  m.pose_world = toMsg(kf.pose_world);
  return m;
}

rekon_msgs::constraint_t constraintMsg(const Constraint& c) {
  rekon_msgs::constraint_t m{};
  m.kind = c.kind == EdgeKind::Loop ? rekon_msgs::constraint_t::KIND_LOOP : rekon_msgs::constraint_t::KIND_ODOMETRY;
  m.from_id = c.from_id;
  m.to_id = c.to_id;
  m.relative = toMsg(c.relative);
  toArray(c.information, m.information);
  return m;
}

rekon_msgs::tracked_frame_t trackedFrameMsg(const TrackedFrame& f) {
  rekon_msgs::tracked_frame_t m{};
  m.frame_id = f.frame_id;
  m.timestamp = f.timestamp;
  m.keyframe_id = f.keyframe_id;
  m.pose_in_keyframe = toMsg(f.pose_in_keyframe);
  m.state = f.lost ? rekon_msgs::tracked_frame_t::STATE_LOST : rekon_msgs::tracked_frame_t::STATE_OK;
  return m;
}

// One record into `contents`, as the inbox converts what arrives (the
// information as it was applied, so unscaled here); false when it is not what
// its tag says.
bool readRecord(const JournalRecord& r, JournalContents& contents) {
  try {
    if (r.tag == kKeyframeRecord) {
      const auto m = decodeRecord<rekon_msgs::keyframe_t>(r);
      if (!m) return false;
      contents.items.emplace_back(keyframeFromMsg(*m));
    } else if (r.tag == kConstraintRecord) {
      const auto m = decodeRecord<rekon_msgs::constraint_t>(r);
      if (!m) return false;
      contents.items.emplace_back(constraintFromMsg(*m, 1.0));
    } else if (r.tag == kTrackedFrameRecord) {
      const auto m = decodeRecord<rekon_msgs::tracked_frame_t>(r);
      if (!m) return false;
      contents.frames.push_back(trackedFrameFromMsg(*m));
    } else if (r.tag == kGraphVersionRecord) {
      const auto m = decodeRecord<rekon_msgs::graph_update_t>(r);
      if (!m) return false;
      contents.newest_version = std::max(contents.newest_version, m->version);
      if (m->final_update) contents.final_update = *m;
    } else {
      return false;
    }
  } catch (const Error&) {  // a non-finite pose or time
    return false;
  }
  ++contents.records_read;
  return true;
}

}  // namespace

JournalContents readJournal(const std::string& path) {
  JournalContents contents;
  readRecordJournal(path, [&contents](const JournalRecord& r) { return readRecord(r, contents); });
  return contents;
}

Journal::Journal(const std::string& out_dir, bool restarted) {
  if (out_dir.empty()) return;
  // A restart appends after the last readable record: a torn one is cut off.
  journal_ = std::make_unique<RecordJournal>((std::filesystem::path(out_dir) / kJournalFile).string(), restarted,
                                             [this](const JournalRecord& r) { return readRecord(r, contents_); });
  journal_->forgetContents();  // what it held is in contents_, converted
}

void Journal::append(const std::vector<GraphItem>& items, const std::vector<TrackedFrame>& frames) {
  if (!journal_) return;
  for (const auto& item : items) {
    if (const auto* kf = std::get_if<KeyframeIn>(&item))
      journal_->append(kKeyframeRecord, keyframeMsg(*kf));
    else
      journal_->append(kConstraintRecord, constraintMsg(std::get<Constraint>(item)));
  }
  for (const auto& f : frames) {
    journal_->append(kTrackedFrameRecord, trackedFrameMsg(f));
    if (!journal_->open()) unwritten_frames_.push_back(f);  // the trajectory still needs it
  }
}

void Journal::noteUpdate(const rekon_msgs::graph_update_t& update) {
  if (!journal_) return;
  rekon_msgs::graph_update_t version_only{};
  version_only.version = update.version;
  journal_->append(kGraphVersionRecord, update.final_update ? update : version_only);
}

std::vector<TrackedFrame> Journal::trackedFrames() const {
  if (!journal_) return {};
  std::map<int64_t, TrackedFrame> by_id;
  scanRecordJournal(journal_->path(), [&by_id](JournalRecord& r) {  // one record in memory at a time
    if (r.tag != kTrackedFrameRecord) return true;
    JournalContents one;
    if (!readRecord(r, one)) return false;
    by_id.emplace(one.frames.front().frame_id, one.frames.front());
    return true;
  });
  for (const TrackedFrame& f : unwritten_frames_) by_id.emplace(f.frame_id, f);
  std::vector<TrackedFrame> out;
  out.reserve(by_id.size());
  for (const auto& [id, f] : by_id) out.push_back(f);
  return out;
}

bool applyArrived(const std::vector<GraphItem>& items, Inbox& inbox, GraphWorker& worker, Journal& journal) {
  std::vector<GraphItem> unseen;
  for (const GraphItem& item : items)
    if (!worker.seen(item)) unseen.push_back(item);
  journal.append(unseen, inbox.takeNewFrames());
  return worker.apply(items);
}

}  // namespace rekon::optimiser
