#include "rekon/frontend_check/checker.hpp"

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "rekon/common/bus.hpp"
#include "rekon/common/messages.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::frontend_check {
namespace {

// Asymmetry tolerated in a covariance or information matrix, relative to its
// largest entry (the optimiser's own tolerance for information matrices).
constexpr double kSymmetryTolerance = 1e-6;
// Negative eigenvalues tolerated in a covariance, relative to the largest:
// rounding of a matrix computed as J^T J and inverted, not a sign error.
constexpr double kEigenvalueTolerance = 1e-9;

using Matrix6 = Eigen::Matrix<double, 6, 6>;

// What is wrong with a 6x6 covariance (definite = false) or information
// matrix (definite = true), or "" when nothing is.
std::string matrixProblem(const double* m, bool definite) {
  const auto a = matrix6FromArray(m);
  if (!a) return "has a non-finite entry";
  const double largest = a->cwiseAbs().maxCoeff();
  if ((*a - a->transpose()).cwiseAbs().maxCoeff() > kSymmetryTolerance * largest) return "is not symmetric";
  if (largest == 0) return definite ? "is zero (an information matrix must be positive definite)" : "";
  const Eigen::SelfAdjointEigenSolver<Matrix6> eig(0.5 * (*a + a->transpose()), Eigen::EigenvaluesOnly);
  const double lo = eig.eigenvalues()[0], hi = eig.eigenvalues()[5];
  if (definite && !(lo > 0)) return "is not positive definite (smallest eigenvalue " + std::to_string(lo) + ")";
  if (!definite && lo < -kEigenvalueTolerance * hi)
    return "is not positive semi-definite (smallest eigenvalue " + std::to_string(lo) + ")";
  return "";
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

}  // namespace

const std::vector<Rule>& rules() {
  static const std::vector<Rule> table = {
      {"FC1", "every message on a frontend channel decodes with this build's schema_version"},
      {"FC2", "a keyframe_t is announced before the first tracked_frame_t that names it"},
      {"FC3", "keyframe ids are announced once; each frame is tracked once"},
      {"FC4", "every pose is finite with a unit quaternion"},
      {"FC5", "covariances are symmetric positive semi-definite; constraint information symmetric positive definite"},
      {"FC6", "graph-update versions increase; an update names only announced keyframes, each once, and keeps every "
              "keyframe an earlier one held"},
      {"FC7", "the last graph update holds every announced keyframe"},
      {"FC8", "every frame is acknowledged under the name the frame source waits for"},
      {"FC9", "every frame is answered by a tracked_frame_t (state ok or lost)"},
      {"FC10", "done_t is sent after the last tracked frame"},
      {"FC11", "each frame is answered within the latency bound"},
  };
  return table;
}

Checker::Checker(CheckOptions options) : options_(std::move(options)) {}

void Checker::offend(const char* id, const std::string& what) {
  if (offences_[id]++ == 0) first_offence_[id] = what;
}

template <class Msg>
bool Checker::decode(const std::string& channel, const void* data, int size, Msg* out) {
  std::string why;
  if (decodeMessage(data, size, out, &why)) return true;
  offend("FC1", "a message on " + channel + " " + why);
  return false;
}

void Checker::checkPose(const std::string& what, const double* t, const double* q) {
  rekon_msgs::pose_t p{};
  std::copy_n(t, 3, p.t);
  std::copy_n(q, 4, p.q);
  if (!fromMsg(p)) offend("FC4", what + " has a non-finite pose or a quaternion that is not unit");
}

void Checker::feed(const std::string& channel, int64_t utime, const void* data, int size) {
  ++messages_;
  if (channel == channel::kFrames) {
    rekon_msgs::frame_t m;
    if (decode(channel, data, size, &m)) onFrame(m.frame_id, utime);
  } else if (channel == channel::kFrameAck) {
    rekon_msgs::frame_ack_t m;
    if (decode(channel, data, size, &m)) onAck(m.service, m.frame_id);
  } else if (channel == channel::kKeyframes) {
    rekon_msgs::keyframe_t m;
    if (decode(channel, data, size, &m)) onKeyframe(m.keyframe_id, m.pose_world.t, m.pose_world.q);
  } else if (channel == channel::kTrackedFrames) {
    rekon_msgs::tracked_frame_t m;
    if (decode(channel, data, size, &m))
      onTracked(m.frame_id, m.keyframe_id, m.pose_in_keyframe.t, m.pose_in_keyframe.q, m.covariance, utime);
  } else if (channel == channel::kConstraints) {
    rekon_msgs::constraint_t m;
    if (decode(channel, data, size, &m)) onConstraint(m.from_id, m.to_id, m.relative.t, m.relative.q, m.information);
  } else if (channel == channel::kGraphUpdates) {
    rekon_msgs::graph_update_t m;
    if (!decode(channel, data, size, &m)) return;
    // The same update sent again (the optimiser repeats its final one: UDP may drop one).
    const std::string bytes(static_cast<const char*>(data), static_cast<size_t>(size));
    if (bytes == last_update_bytes_) return;
    last_update_bytes_ = bytes;
    std::vector<const double*> ts, qs;
    for (const auto& p : m.poses) {
      ts.push_back(p.t);
      qs.push_back(p.q);
    }
    onGraphUpdate(m.version, m.keyframe_ids, ts, qs);
  } else if (channel == channel::kDone) {
    rekon_msgs::done_t m;
    if (decode(channel, data, size, &m)) onDone(m.service, utime);
  } else {
    --messages_;  // not the contract's
  }
}

void Checker::onFrame(int64_t frame_id, int64_t utime) { frame_utime_.emplace(frame_id, utime); }

void Checker::onAck(const std::string& service, int64_t frame_id) {
  if (service == options_.ack_service) acked_up_to_ = std::max(acked_up_to_, frame_id);
}

void Checker::onKeyframe(int64_t keyframe_id, const double* t, const double* q) {
  const std::string what = "keyframe_t " + std::to_string(keyframe_id);
  if (!keyframes_.insert(keyframe_id).second) offend("FC3", what + " was announced again");
  checkPose(what, t, q);
}

void Checker::onTracked(int64_t frame_id, int64_t keyframe_id, const double* t, const double* q,
                        const double* covariance, int64_t utime) {
  const std::string what = "tracked_frame_t " + std::to_string(frame_id);
  if (!keyframes_.count(keyframe_id))
    offend("FC2", what + " names keyframe " + std::to_string(keyframe_id) + " before any keyframe_t announced it");
  if (!tracked_utime_.emplace(frame_id, utime).second) offend("FC3", what + " was tracked again");
  checkPose(what, t, q);
  const std::string problem = matrixProblem(covariance, false);
  if (!problem.empty()) offend("FC5", what + ": its covariance " + problem);
  if (done_utime_ >= 0) offend("FC10", what + " arrived after done_t");
  last_tracked_utime_ = std::max(last_tracked_utime_, utime);
}

void Checker::onConstraint(int64_t from_id, int64_t to_id, const double* t, const double* q,
                           const double* information) {
  const std::string what = "constraint_t " + std::to_string(from_id) + " -> " + std::to_string(to_id);
  checkPose(what, t, q);
  const std::string problem = matrixProblem(information, true);
  if (!problem.empty()) offend("FC5", what + ": its information " + problem);
}

void Checker::onGraphUpdate(int64_t version, const std::vector<int64_t>& ids, const std::vector<const double*>& ts,
                            const std::vector<const double*>& qs) {
  const std::string what = "graph_update_t version " + std::to_string(version);
  if (any_update_ && version < last_version_)
    offend("FC6", what + " goes back from version " + std::to_string(last_version_));
  if (any_update_ && version == last_version_)
    offend("FC6", what + " reuses version " + std::to_string(last_version_) + " with other content");
  const std::set<int64_t> held(ids.begin(), ids.end());
  if (held.size() != ids.size()) offend("FC6", what + " names a keyframe twice");
  for (const int64_t id : ids) {
    if (!keyframes_.count(id)) offend("FC6", what + " names keyframe " + std::to_string(id) + ", never announced");
  }
  for (const int64_t id : last_update_ids_) {
    if (!held.count(id))
      offend("FC6", what + " lacks keyframe " + std::to_string(id) + ", which version " +
                        std::to_string(last_version_) + " held");
  }
  for (size_t i = 0; i < ids.size(); ++i) checkPose(what + ", keyframe " + std::to_string(ids[i]), ts[i], qs[i]);
  any_update_ = true;
  last_version_ = std::max(last_version_, version);
  last_update_ids_ = held;
}

void Checker::onDone(const std::string& service, int64_t utime) {
  if (service == options_.done_service && done_utime_ < 0) done_utime_ = utime;
}

std::vector<RuleResult> Checker::judge() const {
  Checker judged = *this;  // the judgement adds offences found only at the end
  for (const int64_t id : keyframes_) {
    if (!last_update_ids_.count(id))
      judged.offend("FC7", any_update_ ? "the last graph update (version " + std::to_string(last_version_) +
                                             ") lacks keyframe " + std::to_string(id)
                                       : "no graph_update_t arrived (keyframe " + std::to_string(id) + " was announced)");
  }
  std::vector<double> latency_ms;
  for (const auto& [id, utime] : frame_utime_) {
    if (id > acked_up_to_)
      judged.offend("FC8", "frame " + std::to_string(id) + " was never acknowledged as '" + options_.ack_service +
                               "' (acknowledged up to " + std::to_string(acked_up_to_) + ")");
    const auto answered = tracked_utime_.find(id);
    if (answered == tracked_utime_.end()) {
      judged.offend("FC9", "frame " + std::to_string(id) + " got no tracked_frame_t");
      continue;
    }
    const double ms = 1e-3 * static_cast<double>(answered->second - utime);
    latency_ms.push_back(ms);
    if (ms > options_.max_latency_ms)
      judged.offend("FC11", "frame " + std::to_string(id) + " was answered after " + std::to_string(ms) + " ms");
  }
  if (done_utime_ < 0) judged.offend("FC10", "no done_t{service: \"" + options_.done_service + "\"} arrived");

  std::vector<RuleResult> out;
  for (const Rule& rule : rules()) {
    RuleResult r;
    r.rule = rule;
    const auto n = judged.offences_.find(rule.id);
    r.offences = n == judged.offences_.end() ? 0 : n->second;
    r.passed = r.offences == 0;
    if (!r.passed) r.first_offence = judged.first_offence_.at(rule.id);
    out.push_back(r);
  }
  std::ostringstream counts;
  counts << frame_utime_.size() << " frames, " << tracked_utime_.size() << " tracked, " << keyframes_.size()
         << " keyframes";
  out[1].note = counts.str();
  std::ostringstream latency;
  latency.precision(1);
  latency << std::fixed << "median " << percentile(latency_ms, 0.5) << " ms, p95 " << percentile(latency_ms, 0.95)
          << " ms, max " << (latency_ms.empty() ? 0.0 : *std::max_element(latency_ms.begin(), latency_ms.end()))
          << " ms (bound " << options_.max_latency_ms << " ms)";
  out[10].note = latency.str();
  return out;
}

std::string formatResult(const RuleResult& r) {
  std::string line = std::string(r.passed ? "PASS " : "FAIL ") + r.rule.id + "  " + r.rule.summary;
  if (!r.passed) line += ": " + r.first_offence + (r.offences > 1 ? " (and " + std::to_string(r.offences - 1) + " more)" : "");
  if (!r.note.empty()) line += " [" + r.note + "]";
  return line;
}

}  // namespace rekon::frontend_check
