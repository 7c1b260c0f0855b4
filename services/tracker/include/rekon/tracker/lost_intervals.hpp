#pragma once
// Where tracking was lost in a run (issue 18): every run of lost frames as
// one interval, its first reason and how it ended: tracking resumed (a frame
// aligned to the keyframe again), relocalised (a frame placed against one of
// the keyframes, relocaliser.hpp), restarted at the last good pose (a new
// keyframe after max_lost_frames), or the end of the stream. While lost,
// frames carry state lost: the mapper fuses none of them.
#include <cstdint>
#include <string>
#include <vector>

#include "rekon/tracker/tracker.hpp"

namespace rekon::tracker {

struct LostInterval {
  int64_t first_frame = -1, last_frame = -1;  // the lost frames
  int frames = 0;
  double seconds = 0.0;  // from the first lost frame to the frame that ended it (or the last)
  std::string reason;    // the first frame's (toString(LostReason))
  std::string ended;     // "tracking resumed", "relocalised", "restarted at the last good pose", "end of stream"
};

class LostIntervals {
 public:
  // At most this many intervals are kept (the newest; all are counted).
  static constexpr size_t kMaxKept = 1000;

  // Every tracking result, in frame order.
  void add(const TrackResult& r);
  // Ends an open interval with the stream.
  void finish();
  const std::vector<LostInterval>& intervals() const { return intervals_; }
  int64_t count() const { return count_; }
  // The intervals as a JSON array (for stats.json).
  std::string json() const;

 private:
  void close(double end_timestamp, const char* how);
  std::vector<LostInterval> intervals_;
  bool open_ = false;
  double first_timestamp_ = 0.0, last_timestamp_ = 0.0;
  int64_t count_ = 0;
};

}  // namespace rekon::tracker
