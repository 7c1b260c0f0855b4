#include "history.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdint>

#include "rekon/common/messages.hpp"
#include "rekon/tracker/dense_aligner.hpp"
#include "rekon_msgs/replay_end_t.hpp"

namespace rekon::tracker {
namespace {

// A batch at most this long, whatever a request asks: its messages go out
// back to back (about 300 bytes each), well within a receiver's socket buffer.
constexpr int32_t kMaxReplayBatch = 256;

// An odometry or loop constraint (the same fields) as it goes on the bus.
template <class Edge>
rekon_msgs::constraint_t constraintMsg(int8_t kind, const Edge& edge) {
  rekon_msgs::constraint_t c{};
  c.kind = kind;
  c.from_id = edge.from_id;
  c.to_id = edge.to_id;
  c.relative = toMsg(edge.relative);
  toArray(edge.information, c.information);
  return c;
}

}  // namespace

void History::publishResult(const TrackResult& r) {
  std::lock_guard<std::mutex> lock(mutex_);
  rekon_msgs::tracked_frame_t tf{};
  tf.frame_id = r.frame_id;
  tf.timestamp = r.timestamp;
  tf.keyframe_id = r.keyframe_id;
  tf.pose_in_keyframe = toMsg(r.pose_in_keyframe);
  toArray(r.covariance, tf.covariance);
  tf.state = r.state == TrackingState::Ok ? rekon_msgs::tracked_frame_t::STATE_OK : rekon_msgs::tracked_frame_t::STATE_LOST;
  if (r.new_keyframe) {
    rekon_msgs::keyframe_t kf{};
    kf.keyframe_id = r.keyframe_id;
    kf.frame_id = r.frame_id;
    kf.timestamp = r.timestamp;
    kf.pose_world = toMsg(r.keyframe_pose_world);
    keyframes_.push_back(kf);
    keyframe_of_frame_[r.frame_id] = kf;
    journal(kKeyframeRecord, kf);
    bus_.publish(channel::kKeyframes, kf);
    announced_for_[r.keyframe_id] = mapper_instance_;
  } else if (r.keyframe_id >= 0) {
    announceAgain(r.keyframe_id);
  }
  const auto publish_edge = [&](int8_t kind, const OdometryConstraint& edge) {
    const rekon_msgs::constraint_t c = constraintMsg(kind, edge);
    constraints_.add(c, journal(kConstraintRecord, c));
    bus_.publish(channel::kConstraints, c);
  };
  if (r.odometry) publish_edge(rekon_msgs::constraint_t::KIND_ODOMETRY, *r.odometry);
  if (r.relocalised_from) publish_edge(rekon_msgs::constraint_t::KIND_LOOP, *r.relocalised_from);
  if (r.reuse_edge) publish_edge(rekon_msgs::constraint_t::KIND_LOOP, *r.reuse_edge);
  noteTrackedFrame(tf, journal(kTrackedFrameRecord, tf));
  bus_.publish(channel::kTrackedFrames, tf);
}

std::vector<History::FrameEntry>::iterator History::firstFrameFrom(int64_t frame_id) {
  return std::lower_bound(frames_.begin(), frames_.end(), frame_id,
                          [](const FrameEntry& e, int64_t id) { return e.frame_id < id; });
}

void History::noteTrackedFrame(const rekon_msgs::tracked_frame_t& tf, std::optional<uint64_t> offset) {
  // Frames come in id order; one tracked again after a restart replaces the first.
  auto at = frames_.end();
  if (!frames_.empty() && tf.frame_id <= frames_.back().frame_id)
    at = firstFrameFrom(tf.frame_id);
  if (at != frames_.end() && at->frame_id == tf.frame_id) {
    tracked_log_.replace(at->index, tf, offset);
    at->published_for = mapper_instance_;
    return;
  }
  frames_.insert(at, FrameEntry{tf.frame_id, static_cast<uint32_t>(tracked_log_.size()), mapper_instance_});
  tracked_log_.add(tf, offset);
}

void History::publishLoopConstraint(const LoopConstraint& l) {
  const rekon_msgs::constraint_t c = constraintMsg(rekon_msgs::constraint_t::KIND_LOOP, l);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    constraints_.add(c, journal(kConstraintRecord, c));
  }
  bus_.publish(channel::kConstraints, c);
  spdlog::info("loop closure {} -> {} (ln det ratios coarse {:.2f}, fine {:.2f}, {} pixels)", l.from_id, l.to_id,
               l.coarse_ratio, l.fine_ratio, l.valid_pixels);
}

void History::noteLoopChecked(int64_t id) {
  rekon_msgs::keyframe_t kf{};
  kf.keyframe_id = id;
  kf.pose_world = toMsg(Pose::Identity());
  std::lock_guard<std::mutex> lock(mutex_);
  journal(kLoopCheckedRecord, kf);
}

bool History::republishResult(int64_t frame_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto entry = firstFrameFrom(frame_id);
  if (entry == frames_.end() || entry->frame_id != frame_id) return false;
  if (entry->published_for >= mapper_instance_) return true;
  entry->published_for = mapper_instance_;
  if (auto kf = keyframe_of_frame_.find(frame_id); kf != keyframe_of_frame_.end()) {
    bus_.publish(channel::kKeyframes, kf->second);
    announced_for_[kf->second.keyframe_id] = mapper_instance_;
  }
  if (const auto tf = tracked_log_.at(entry->index)) bus_.publish(channel::kTrackedFrames, *tf);
  return true;
}

void History::addReplayRequest(const rekon_msgs::replay_request_t& request) {
  std::lock_guard<std::mutex> lock(mutex_);
  requests_.push_back(request);
}

void History::serveReplays() {
  std::vector<rekon_msgs::replay_request_t> requests;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    requests.swap(requests_);
  }
  for (const auto& r : requests) serveBatch(r);
}

void History::serveBatch(const rekon_msgs::replay_request_t& r) {
  std::vector<rekon_msgs::keyframe_t> keyframes;
  std::vector<rekon_msgs::constraint_t> constraints;
  std::vector<rekon_msgs::tracked_frame_t> tracked;
  rekon_msgs::replay_end_t end{};
  {
    std::lock_guard<std::mutex> lock(mutex_);
    // Keyframes first, then constraints (each edge's keyframes before it),
    // then tracked frames, from the requester's cursor, max_items in all.
    size_t budget = static_cast<size_t>(std::clamp(r.max_items, 0, kMaxReplayBatch));
    // From `next` on, while the budget lasts; `get(i)` nullopt: a message the journal could not give back
    // (logged there), skipped. Returns the next cursor.
    const auto take = [&budget](size_t size, int64_t next, auto get, auto& into) {
      size_t i = static_cast<size_t>(std::max<int64_t>(0, next));
      for (; i < size && budget > 0; ++i, --budget) {
        if (auto m = get(i)) into.push_back(std::move(*m));
      }
      return static_cast<int64_t>(i);
    };
    end.next_keyframe = take(keyframes_.size(), r.next_keyframe,
                             [this](size_t i) { return std::optional(keyframes_[i]); }, keyframes);
    end.next_constraint = take(constraints_.size(), r.next_constraint,
                               [this](size_t i) { return constraints_.at(i); }, constraints);
    const auto first = firstFrameFrom(r.next_frame_id);
    const auto first_index = static_cast<int64_t>(first - frames_.begin());
    const int64_t next_index = take(frames_.size(), first_index,
                                    [this](size_t i) { return tracked_log_.at(frames_[i].index); }, tracked);
    end.next_frame_id = next_index > first_index ? frames_[static_cast<size_t>(next_index) - 1].frame_id + 1
                                                 : r.next_frame_id;
    end.complete = end.next_keyframe >= static_cast<int64_t>(keyframes_.size()) &&
                   end.next_constraint >= static_cast<int64_t>(constraints_.size()) &&
                   (frames_.empty() || end.next_frame_id > frames_.back().frame_id);
    end.keyframes = static_cast<int64_t>(keyframes_.size());
    end.constraints = static_cast<int64_t>(constraints_.size());
    end.tracked_frames = static_cast<int64_t>(frames_.size());
    end.last_frame_id = frames_.empty() ? -1 : frames_.back().frame_id;
    end.graph_version = graph_version_;
    end.done = done_;
  }
  for (const auto& m : keyframes) bus_.publish(channel::kKeyframesResent, m);
  for (const auto& m : constraints) bus_.publish(channel::kConstraintsResent, m);
  for (const auto& m : tracked) bus_.publish(channel::kTrackedFramesResent, m);
  end.service = r.service;
  end.pid = r.pid;
  end.request_id = r.request_id;
  bus_.publish(channel::kReplayEnd, end);
  spdlog::debug("replayed {} keyframes, {} constraints and {} tracked frames for rekon-{} (pid {}){}", keyframes.size(),
                constraints.size(), tracked.size(), r.service, r.pid, end.complete ? ": complete" : "");
}

void History::noteGraphVersion(int64_t version) {
  std::lock_guard<std::mutex> lock(mutex_);
  graph_version_ = std::max(graph_version_, version);
}

void History::markDone(const std::optional<rekon_msgs::done_t>& done) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!done_ && done) journal(kDoneRecord, *done);
  done_ = true;
}

bool History::readable(const JournalRecord& r) {
  switch (r.tag) {
    case kKeyframeRecord:
    case kLoopCheckedRecord: return decodeRecord<rekon_msgs::keyframe_t>(r).has_value();
    case kConstraintRecord: return decodeRecord<rekon_msgs::constraint_t>(r).has_value();
    case kTrackedFrameRecord: return decodeRecord<rekon_msgs::tracked_frame_t>(r).has_value();
    case kDoneRecord: return decodeRecord<rekon_msgs::done_t>(r).has_value();
    default: return false;
  }
}

namespace {

// Where odometry stood after the newest journaled frame (OdometryState),
// followed frame by frame as the journal is read.
class OdometryFollower {
 public:
  // A tracked frame newer than every one before it; `keyframe_pose` null when its keyframe is unknown.
  void newest(const rekon_msgs::tracked_frame_t& tf, const Pose& in_keyframe, const Pose* keyframe_pose) {
    std::optional<Pose> world;
    if (tf.state == rekon_msgs::tracked_frame_t::STATE_OK && keyframe_pose) world = *keyframe_pose * in_keyframe;
    state_.reset();
    if (world) {
      OdometryState s;
      s.keyframe_id = tf.keyframe_id;
      s.in_keyframe = in_keyframe;
      s.timestamp = tf.timestamp;
      if (last_world_) {
        s.velocity = last_world_->inverse() * *world;
        s.velocity_dt = tf.timestamp - last_timestamp_;
      }
      state_ = s;
    }
    last_world_ = world;
    last_timestamp_ = tf.timestamp;
  }
  // Any good tracked frame: the first one aligned against a keyframe since
  // tracking switched to it sets the reference entropy (a keyframe's own
  // frame has no covariance; a reused keyframe's is the reusing frame's).
  void aligned(const rekon_msgs::tracked_frame_t& tf) {
    if (tf.state != rekon_msgs::tracked_frame_t::STATE_OK) return;
    if (tf.keyframe_id != run_keyframe_) {
      run_keyframe_ = tf.keyframe_id;
      run_entropy_.reset();
    }
    const auto covariance = matrix6FromArray(tf.covariance);
    if (covariance && !covariance->isZero() && !run_entropy_) run_entropy_ = entropyOfInformation(covariance->inverse());
  }
  // At the end: the newest frame made keyframe `own_keyframe` (-1: none), whose incoming edge has `own_entropy`.
  std::optional<OdometryState> state(int64_t own_keyframe, std::optional<double> own_entropy) const {
    if (!state_) return std::nullopt;
    OdometryState s = *state_;
    if (run_keyframe_ == s.keyframe_id) s.reference_entropy = run_entropy_;
    if (own_keyframe == s.keyframe_id) s.keyframe_entropy = own_entropy;
    return s;
  }

 private:
  std::optional<OdometryState> state_;
  std::optional<Pose> last_world_;
  double last_timestamp_ = 0.0;
  int64_t run_keyframe_ = -1;  // the keyframe the newest good frames were tracked against
  std::optional<double> run_entropy_;
};

}  // namespace

RestoredJournal History::restore(const JournalRead& read) {
  std::lock_guard<std::mutex> lock(mutex_);
  RestoredJournal out;
  std::map<int64_t, size_t> keyframe_index;  // id -> index in out.keyframes
  std::map<int64_t, Pose> keyframe_pose;
  OdometryFollower odometry;
  // What was read, with where odometry stood after it (also when an undecodable record ends the read).
  const auto finish = [&]() {
    const auto own = keyframe_of_frame_.find(out.last_frame_id);
    const auto index = own == keyframe_of_frame_.end() ? keyframe_index.end() : keyframe_index.find(own->second.keyframe_id);
    std::optional<double> own_entropy;
    if (index != keyframe_index.end() && out.keyframes[index->second].incoming)
      own_entropy = out.keyframes[index->second].incoming->entropy;
    out.odometry_state =
        odometry.state(own == keyframe_of_frame_.end() ? -1 : own->second.keyframe_id, own_entropy);
    return std::move(out);
  };
  const auto undecodable = [&](size_t i, const char* what) {
    spdlog::error("{}: record {} of {} does not decode as {}; the {} records after it are not restored",
                  journal_ ? journal_->path() : std::string("journal"), i + 1, read.records.size(), what,
                  read.records.size() - i - 1);
  };
  for (size_t i = 0; i < read.records.size(); ++i) {
    const JournalRecord& record = read.records[i];
    if (record.tag == kKeyframeRecord) {
      const auto kf = decodeRecord<rekon_msgs::keyframe_t>(record);
      const auto pose = kf ? fromMsg(kf->pose_world) : std::nullopt;
      if (!pose) {
        undecodable(i, "a keyframe");
        return finish();
      }
      keyframes_.push_back(*kf);
      keyframe_of_frame_[kf->frame_id] = *kf;
      keyframe_index[kf->keyframe_id] = out.keyframes.size();
      keyframe_pose[kf->keyframe_id] = *pose;
      out.keyframes.push_back({*kf, std::nullopt});
    } else if (record.tag == kConstraintRecord) {
      const auto c = decodeRecord<rekon_msgs::constraint_t>(record);
      if (!c) {
        undecodable(i, "a constraint");
        return finish();
      }
      constraints_.add(*c, record.offset);
      ++out.constraints;
      const auto to = keyframe_index.find(c->to_id);
      const auto relative = fromMsg(c->relative);
      const auto information = matrix6FromArray(c->information);
      if (c->kind == rekon_msgs::constraint_t::KIND_ODOMETRY && to != keyframe_index.end() && relative && information) {
        OdometryConstraint edge;
        edge.from_id = c->from_id;
        edge.to_id = c->to_id;
        edge.relative = *relative;
        edge.information = *information;
        edge.entropy = entropyOfInformation(*information);
        out.keyframes[to->second].incoming = edge;
      }
    } else if (record.tag == kTrackedFrameRecord) {
      const auto tf = decodeRecord<rekon_msgs::tracked_frame_t>(record);
      const auto in_keyframe = tf ? fromMsg(tf->pose_in_keyframe) : std::nullopt;
      if (!in_keyframe) {
        undecodable(i, "a tracked frame");
        return finish();
      }
      noteTrackedFrame(*tf, record.offset);
      ++out.tracked_frames;
      const auto kf = keyframe_pose.find(tf->keyframe_id);
      if (kf != keyframe_pose.end()) out.odometry.push_back({tf->timestamp, kf->second * *in_keyframe});
      odometry.aligned(*tf);
      if (tf->frame_id > out.last_frame_id) {
        out.last_frame_id = tf->frame_id;
        if (kf != keyframe_pose.end()) out.last_pose_world = kf->second * *in_keyframe;
        odometry.newest(*tf, *in_keyframe, kf != keyframe_pose.end() ? &kf->second : nullptr);
      }
    } else if (record.tag == kLoopCheckedRecord) {
      const auto kf = decodeRecord<rekon_msgs::keyframe_t>(record);
      if (!kf) {
        undecodable(i, "a loop check");
        return finish();
      }
      out.loop_checked.insert(kf->keyframe_id);
    } else if (record.tag == kDoneRecord) {
      const auto done = decodeRecord<rekon_msgs::done_t>(record);
      if (!done) {
        undecodable(i, "done");
        return finish();
      }
      out.done = *done;
      done_ = true;
    } else {
      {
        undecodable(i, "a tracker record (unknown tag)");
        return finish();
      }
    }
  }
  return finish();
}

void History::publishArchived(const rekon_msgs::keyframe_t& kf, const std::optional<OdometryConstraint>& incoming) {
  std::lock_guard<std::mutex> lock(mutex_);
  keyframes_.push_back(kf);
  keyframe_of_frame_[kf.frame_id] = kf;
  journal(kKeyframeRecord, kf);
  bus_.publish(channel::kKeyframes, kf);
  if (!incoming) return;
  const rekon_msgs::constraint_t c = constraintMsg(rekon_msgs::constraint_t::KIND_ODOMETRY, *incoming);
  constraints_.add(c, journal(kConstraintRecord, c));
  bus_.publish(channel::kConstraints, c);
}

void History::announceAgain(int64_t keyframe_id) {
  int& announced = announced_for_[keyframe_id];
  if (announced >= mapper_instance_) return;
  announced = mapper_instance_;
  const auto kf = std::find_if(keyframes_.rbegin(), keyframes_.rend(),
                               [keyframe_id](const rekon_msgs::keyframe_t& k) { return k.keyframe_id == keyframe_id; });
  if (kf != keyframes_.rend()) bus_.publish(channel::kKeyframes, *kf);
}

bool History::noteMapperPid(int pid) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!mapper_pids_.insert(pid).second || mapper_pids_.size() == 1) return false;
  ++mapper_instance_;
  return true;
}

}  // namespace rekon::tracker
