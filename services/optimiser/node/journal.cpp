#include "journal.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <filesystem>
#include <sstream>
#include <variant>

#include "rekon/common/error.hpp"

namespace rekon::optimiser {
namespace {

void appendPose(const Pose& pose, std::string& out) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) out += fmt::format(" {:.17g}", pose.matrix()(r, c));
}

std::string lineOf(const GraphItem& item) {
  std::string out;
  if (const auto* kf = std::get_if<KeyframeIn>(&item)) {
    out = fmt::format("K {}", kf->id);
    appendPose(kf->pose_world, out);
  } else {
    const auto& c = std::get<Constraint>(item);
    out = fmt::format("{} {} {}", c.kind == EdgeKind::Loop ? 'L' : 'O', c.from_id, c.to_id);
    appendPose(c.relative, out);
    for (int i = 0; i < 36; ++i) out += fmt::format(" {:.17g}", c.information(i / 6, i % 6));
  }
  return out + '\n';
}

std::string lineOf(const TrackedFrame& f) {
  std::string out = fmt::format("F {} {:.17g} {} {}", f.frame_id, f.timestamp, f.keyframe_id, f.lost ? 1 : 0);
  appendPose(f.pose_in_keyframe, out);
  return out + '\n';
}

// Reads a line's fields in order; any that is missing or not finite, or one
// too many, makes the line unreadable.
class Fields {
 public:
  explicit Fields(const std::string& line) : in_(line) {}
  template <typename T>
  T next() {
    T v{};
    if (!(in_ >> v)) ok_ = false;
    if constexpr (std::is_floating_point_v<T>) ok_ = ok_ && std::isfinite(v);
    return v;
  }
  Pose pose() {
    Pose p = Pose::Identity();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) p.matrix()(r, c) = next<double>();
    return p;
  }
  bool complete() {
    std::string extra;
    return ok_ && !(in_ >> extra);
  }

 private:
  std::istringstream in_;
  bool ok_ = true;
};

// One line into `contents`; false when it is unreadable.
bool readLine(const std::string& line, JournalContents& contents) {
  Fields f(line);
  const std::string tag = f.next<std::string>();
  if (tag == "K") {
    KeyframeIn kf;
    kf.id = f.next<int64_t>();
    kf.pose_world = f.pose();
    if (!f.complete()) return false;
    contents.items.emplace_back(kf);
  } else if (tag == "O" || tag == "L") {
    Constraint c;
    c.kind = tag == "L" ? EdgeKind::Loop : EdgeKind::Odometry;
    c.from_id = f.next<int64_t>();
    c.to_id = f.next<int64_t>();
    c.relative = f.pose();
    for (int i = 0; i < 36; ++i) c.information(i / 6, i % 6) = f.next<double>();
    if (!f.complete()) return false;
    contents.items.emplace_back(c);
  } else if (tag == "F") {
    TrackedFrame t;
    t.frame_id = f.next<int64_t>();
    t.timestamp = f.next<double>();
    t.keyframe_id = f.next<int64_t>();
    t.lost = f.next<int>() != 0;
    t.pose_in_keyframe = f.pose();
    if (!f.complete()) return false;
    contents.frames.push_back(t);
  } else {
    return false;
  }
  return true;
}

}  // namespace

JournalContents readJournal(const std::string& path) {
  JournalContents contents;
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    // A line without its newline was cut short by a kill: unreadable too.
    if (in.eof() || !readLine(line, contents)) {
      spdlog::warn("{} line {} is torn or unreadable; what follows it is asked for from the tracker again", path,
                   contents.lines_read + 1);
      break;
    }
    ++contents.lines_read;
    contents.bytes_read += line.size() + 1;
  }
  return contents;
}

Journal::Journal(const std::string& out_dir, bool restarted) {
  if (out_dir.empty()) return;
  path_ = (std::filesystem::path(out_dir) / kJournalFile).string();
  std::error_code ec;
  if (restarted && std::filesystem::exists(path_)) {
    contents_ = readJournal(path_);
    // A restart appends after the last readable line: a torn one is cut off.
    std::filesystem::resize_file(path_, contents_.bytes_read, ec);
  }
  out_.open(path_, restarted ? std::ios::app : std::ios::trunc);
  if (ec || !out_) throw Error("cannot write the optimiser's journal " + path_ + "; check that the folder is writable");
}

void Journal::append(const std::vector<GraphItem>& items, const std::vector<TrackedFrame>& frames) {
  if (!out_.is_open() || (items.empty() && frames.empty())) return;
  std::string text;
  for (const auto& item : items) text += lineOf(item);
  for (const auto& f : frames) text += lineOf(f);
  out_ << text;
  out_.flush();
  if (!out_) {
    spdlog::error("cannot append to {} (disk full?); no more journal: a restart of this optimiser asks the tracker "
                  "for everything after it",
                  path_);
    out_.close();
  }
}

bool applyArrived(const std::vector<GraphItem>& items, Inbox& inbox, GraphWorker& worker, Journal& journal) {
  std::vector<GraphItem> unseen;
  for (const GraphItem& item : items)
    if (!worker.seen(item)) unseen.push_back(item);
  journal.append(unseen, inbox.takeNewFrames());
  return worker.apply(items);
}

}  // namespace rekon::optimiser
