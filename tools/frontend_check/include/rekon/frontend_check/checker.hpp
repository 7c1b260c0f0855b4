#pragma once
// The frontend contract (messages/FRONTEND.md) as code: a Checker is fed the
// bus traffic of a run (live or from an lcm-logger log), message by message
// with its receive time, and judges it against every rule of the contract.
// It knows the bus only as (channel, time, bytes): where they come from is
// the command's business (frontend_check.hpp).
#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>

namespace rekon::frontend_check {

// One rule of messages/FRONTEND.md: its id there and a one-line summary.
struct Rule {
  const char* id;
  const char* summary;
};
// Every rule, in the order the contract lists them.
const std::vector<Rule>& rules();

struct CheckOptions {
  // The name the frame source waits for (player.wait_for): the frontend acknowledges frames under it.
  std::string ack_service = "tracker";
  // The service whose done_t ends the frontend's work for the mapper.
  std::string done_service = "optimiser";
  // A frame answered later than this (frame_t to tracked_frame_t) holds a live source back.
  double max_latency_ms = kDefaultMaxLatencyMs;
  static constexpr double kDefaultMaxLatencyMs = 1000.0;
};

struct RuleResult {
  Rule rule;
  bool passed = true;
  int64_t offences = 0;
  std::string first_offence;  // the first offending message, in words
  std::string note;           // what was checked (counts, latency percentiles)
};

class Checker {
 public:
  explicit Checker(CheckOptions options = {});

  // One message as it crossed the bus: the channel without its prefix, the
  // receive time in microseconds, the encoded bytes. Channels the contract
  // does not cover are ignored.
  void feed(const std::string& channel, int64_t utime, const void* data, int size);

  // Whether the frontend's done_t has arrived (a live check stops soon after).
  bool frontendDone() const { return done_utime_ >= 0; }
  int64_t messages() const { return messages_; }

  // Every rule judged on what was fed so far.
  std::vector<RuleResult> judge() const;

 private:
  void offend(const char* id, const std::string& what);
  template <class Msg>
  bool decode(const std::string& channel, const void* data, int size, Msg* out);
  void onFrame(int64_t frame_id, int64_t utime);
  void onAck(const std::string& service, int64_t frame_id);
  void onKeyframe(int64_t keyframe_id, const double* t, const double* q);
  void onTracked(int64_t frame_id, int64_t keyframe_id, const double* t, const double* q, const double* covariance,
                 int64_t utime);
  void onConstraint(int64_t from_id, int64_t to_id, const double* t, const double* q, const double* information);
  void onGraphUpdate(int64_t version, const std::vector<int64_t>& ids, const std::vector<const double*>& ts,
                     const std::vector<const double*>& qs);
  void onDone(const std::string& service, int64_t utime);
  void checkPose(const std::string& what, const double* t, const double* q);

  CheckOptions options_;
  int64_t messages_ = 0;
  std::map<int64_t, int64_t> frame_utime_;     // frame_t: id -> receive time
  int64_t acked_up_to_ = -1;                    // cumulative acknowledgement under ack_service
  std::set<int64_t> keyframes_;                 // announced
  std::map<int64_t, int64_t> tracked_utime_;    // tracked_frame_t: frame id -> receive time
  int64_t last_tracked_utime_ = -1;
  int64_t last_version_ = -1;
  bool any_update_ = false;
  std::set<int64_t> last_update_ids_;           // the newest graph update's keyframes
  std::string last_update_bytes_;               // and its encoding (a repeat of it is no new update)
  int64_t done_utime_ = -1;
  std::map<std::string, int64_t> offences_;
  std::map<std::string, std::string> first_offence_;
};

// "PASS FC2 keyframe-first ..." / "FAIL FC2 ...: first offence" (one line).
std::string formatResult(const RuleResult& r);

}  // namespace rekon::frontend_check
