#include "rekon/tracker/lost_intervals.hpp"

#include <fmt/format.h>

#include "rekon/common/json.hpp"

namespace rekon::tracker {

void LostIntervals::add(const TrackResult& r) {
  if (r.state == TrackingState::Ok) {
    if (open_) close(r.timestamp, r.relocalised_from ? "relocalised" : "tracking resumed");
    return;
  }
  if (!open_) {
    open_ = true;
    ++count_;
    if (intervals_.size() == kMaxKept) intervals_.erase(intervals_.begin());
    intervals_.push_back({r.frame_id, r.frame_id, 0, 0.0, toString(r.lost_reason), ""});
    first_timestamp_ = r.timestamp;
  }
  LostInterval& i = intervals_.back();
  i.last_frame = r.frame_id;
  ++i.frames;
  last_timestamp_ = r.timestamp;
  if (r.keyframe_reset) close(r.timestamp, "restarted at the last good pose");
}

void LostIntervals::finish() {
  if (open_) close(last_timestamp_, "end of stream");
}

void LostIntervals::close(double end_timestamp, const char* how) {
  LostInterval& i = intervals_.back();
  i.seconds = end_timestamp - first_timestamp_;
  i.ended = how;
  open_ = false;
}

std::string LostIntervals::json() const {
  std::string out = "[";
  for (const LostInterval& i : intervals_) {
    out += fmt::format(R"({}{{"first_frame":{},"last_frame":{},"frames":{},"seconds":{:.3f},"reason":{},"ended":{}}})",
                       out.size() > 1 ? "," : "", i.first_frame, i.last_frame, i.frames, i.seconds, jsonString(i.reason),
                       jsonString(i.ended.empty() ? "open" : i.ended));
  }
  return out + "]";
}

}  // namespace rekon::tracker
