#include "inbox.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "rekon/common/error.hpp"
#include "rekon/common/frame_ack.hpp"
#include "rekon/common/messages.hpp"

namespace rekon::mapper {

Inbox::Inbox(ServiceContext& ctx, size_t max_queued_frames, bool drop_when_full)
    : ctx_(ctx), max_queued_(max_queued_frames), drop_when_full_(drop_when_full), peers_(ctx.bus(), ctx.lifecycle()) {}

// Frames before the resume point are not marked as seen: the source sends
// none of its own again after the restart (it rewinds to the resume point,
// and before it heard of the restart it was past it), so one that comes is a
// new stream's (a new player numbers from 0 again) and is fused.
void Inbox::resumeFrom(int64_t first_missing_frame, double rewind_wait_s) {
  if (first_missing_frame < 0) return;
  std::lock_guard<std::mutex> lock(mutex_);
  awaiting_frame_ = rewind_wait_s > 0 ? first_missing_frame : -1;  // a live source never rewinds
  rewind_wait_s_ = rewind_wait_s;
  resumed_from_ = first_missing_frame;
}

bool Inbox::away(const std::string& service, double never_heard_s) const {
  return peers_.gone(service) ||
         (!peers_.peer(service) &&
          std::chrono::steady_clock::now() - started_ > std::chrono::duration<double>(never_heard_s));
}

bool Inbox::resendUnderWay() const {
  if (resumed_from_ <= 0 || rewind_wait_s_ <= 0 || end_frame_ == kNoEndYet || last_resolved_ >= end_frame_ ||
      end_frame_ < resumed_from_)
    return false;
  return std::chrono::steady_clock::now() - last_frame_at_ < std::chrono::duration<double>(rewind_wait_s_);
}

bool Inbox::beforeResume(int64_t id) {
  if (awaiting_frame_ < 0 || id < awaiting_frame_) return false;  // before it: in the store, a copy
  const auto now = std::chrono::steady_clock::now();
  const bool rewound = id == awaiting_frame_ || (newest_before_resume_ >= 0 && id < newest_before_resume_) ||
                       (newest_before_resume_ >= 0 &&
                        std::chrono::duration<double>(now - first_before_resume_).count() > rewind_wait_s_);
  if (rewound) {
    awaiting_frame_ = -1;
    return false;
  }
  if (newest_before_resume_ < 0) first_before_resume_ = now;
  newest_before_resume_ = std::max(newest_before_resume_, id);
  ++counts_.frames_before_resume;
  return true;
}

void Inbox::subscribe() {
  Bus& bus = ctx_.bus();
  bus.subscribe<rekon_msgs::frame_t>(channel::kFrames, [this](const rekon_msgs::frame_t& m) { onFrame(m); });
  bus.subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFrames,
                                             [this](const rekon_msgs::tracked_frame_t& m) { onTrackedFrame(m); });
  bus.subscribe<rekon_msgs::keyframe_t>(channel::kKeyframes, [this](const rekon_msgs::keyframe_t& m) { onKeyframe(m); });
  bus.subscribe<rekon_msgs::graph_update_t>(channel::kGraphUpdates,
                                            [this](const rekon_msgs::graph_update_t& m) { onGraphUpdate(m); });
  bus.subscribe<rekon_msgs::end_of_stream_t>(channel::kEndOfStream,
                                             [this](const rekon_msgs::end_of_stream_t& m) { onEndOfStream(m); });
}

void Inbox::onFrame(const rekon_msgs::frame_t& msg) {
  std::optional<bool> again_ack;  // set for a frame sent again: whether to acknowledge it now
  {
    std::lock_guard<std::mutex> lock(mutex_);
    last_frame_at_ = std::chrono::steady_clock::now();
    if (beforeResume(msg.frame_id)) {
      spdlog::info("frame {} came before frame {}, the resume point: sent before the restart was heard of; it comes "
                   "again in order", msg.frame_id, awaiting_frame_);
      return;
    }
    if (seen(msg.frame_id)) {
      // Sent again: the first copy is (or was) in the work. Acknowledged
      // again unless its acknowledgement is still held back.
      ++counts_.frames_received_again;
      again_ack = !ackDeferred(msg.frame_id);
    }
  }
  if (again_ack) {
    if (*again_ack) ack(msg.frame_id);
    return;
  }
  Intrinsics k;
  std::optional<RgbdFrame> frame = receiver_.receive(msg, &k);  // a copy out of the ring: safe to acknowledge
  bool ack_now = true;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (frame && drop_when_full_ && queuedFrames() >= max_queued_) {
      ++counts_.dropped_frames;
      ++counts_.dropped_when_full;
      dropped_when_full_.insert(msg.frame_id);  // its tracked frame is not a second drop
    } else if (frame) {
      // A tracked frame older than this image whose image never came (dropped by the transport) never will.
      while (!tracked_.empty() && tracked_.begin()->first < msg.frame_id) {
        last_resolved_ = std::max(last_resolved_, tracked_.begin()->first);
        tracked_.erase(tracked_.begin());
        ++counts_.dropped_frames;
      }
      images_[msg.frame_id] = {std::move(*frame), k};
      join(msg.frame_id);
      if (queuedFrames() > max_queued_) {
        deferred_acks_.push_back(msg.frame_id);
        ack_now = false;
      }
    } else {
      ++counts_.dropped_frames;
    }
  }
  if (ack_now) ack(msg.frame_id);
  ctx_.setLastFrame(msg.frame_id);
}

void Inbox::onTrackedFrame(const rekon_msgs::tracked_frame_t& msg) {
  const auto pose = fromMsg(msg.pose_in_keyframe);
  std::lock_guard<std::mutex> lock(mutex_);
  if (!pose) {
    spdlog::error("tracked frame {}: invalid pose_in_keyframe; dropped", msg.frame_id);
    last_resolved_ = std::max(last_resolved_, msg.frame_id);
    return;
  }
  // Tracked frames come in order: the images dropped when full up to this one are settled.
  const bool image_dropped = dropped_when_full_.erase(msg.frame_id) > 0;
  dropped_when_full_.erase(dropped_when_full_.begin(), dropped_when_full_.lower_bound(msg.frame_id));
  if (image_dropped) {
    last_resolved_ = std::max(last_resolved_, msg.frame_id);
    return;
  }
  // Tracked frames come in order: older images without one will never get it.
  while (!images_.empty() && images_.begin()->first < msg.frame_id) {
    spdlog::warn("frame {}: no tracked frame came for it; dropped", images_.begin()->first);
    last_resolved_ = std::max(last_resolved_, images_.begin()->first);
    images_.erase(images_.begin());
    ++counts_.dropped_frames;
  }
  tracked_[msg.frame_id] = {msg.keyframe_id, *pose, msg.state == rekon_msgs::tracked_frame_t::STATE_LOST};
  join(msg.frame_id);
}

void Inbox::onKeyframe(const rekon_msgs::keyframe_t& msg) {
  const auto pose = fromMsg(msg.pose_world);
  if (!pose) {
    spdlog::error("keyframe {}: invalid pose_world; dropped", msg.keyframe_id);
    return;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  queue_.push_back(KeyframeWork{msg.keyframe_id, *pose});
  work_ready_.notify_one();
}

void Inbox::onGraphUpdate(const rekon_msgs::graph_update_t& msg) {
  if (!filter_.accept(msg.version)) return;
  GraphWork g{msg.version, {}};
  try {
    g.poses = graphPoses(msg);
  } catch (const Error& e) {
    spdlog::error("{}", e.what());
    return;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  // Every update carries all poses: a newer one replaces one still waiting.
  for (Work& w : queue_) {
    if (std::holds_alternative<GraphWork>(w)) {
      w = std::move(g);
      ++counts_.coalesced_updates;
      return;
    }
  }
  queue_.push_back(std::move(g));
  work_ready_.notify_one();
}

void Inbox::onEndOfStream(const rekon_msgs::end_of_stream_t& m) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (end_frame_ == m.last_frame_id) return;  // the source repeats it: a lost one would cost the end
  end_frame_ = m.last_frame_id;
  spdlog::info("end of stream after frame {} ({} frames)", m.last_frame_id, m.frames);
}

void Inbox::ack(int64_t frame_id) { publishFrameAck(ctx_, frame_id); }

void Inbox::join(int64_t id) {
  auto img = images_.find(id);
  auto tr = tracked_.find(id);
  if (img == images_.end() || tr == tracked_.end()) return;
  queue_.push_back(FrameWork{std::move(img->second.first), img->second.second, tr->second});
  ++frames_in_queue_;
  images_.erase(img);
  tracked_.erase(tr);
  last_resolved_ = std::max(last_resolved_, id);
  work_ready_.notify_one();
}

bool Inbox::ackDeferred(int64_t id) const {
  return std::find(deferred_acks_.begin(), deferred_acks_.end(), id) != deferred_acks_.end();
}

std::optional<Work> Inbox::next() {
  std::unique_lock<std::mutex> lock(mutex_);
  work_ready_.wait(lock, [&] { return stop_worker_ || !queue_.empty(); });
  if (queue_.empty()) return std::nullopt;
  Work w = std::move(queue_.front());
  queue_.pop_front();
  busy_ = true;
  return w;
}

bool Inbox::waitForWork(std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  return work_ready_.wait_for(lock, timeout, [&] { return stop_worker_ || !queue_.empty(); });
}

void Inbox::finished(bool was_frame, const MapperCounters& progress) {
  std::vector<int64_t> release;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    busy_ = false;
    progress_ = progress;
    if (was_frame) --frames_in_queue_;
    while (!deferred_acks_.empty() && queuedFrames() <= max_queued_) {
      release.push_back(deferred_acks_.front());
      deferred_acks_.pop_front();
    }
    if (queue_.empty()) idle_.notify_all();
  }
  for (int64_t id : release) ack(id);
}

void Inbox::failed(const std::string& error) {
  std::lock_guard<std::mutex> lock(mutex_);
  worker_error_ = error;
  busy_ = false;
  idle_.notify_all();
}

bool Inbox::streamOver(bool wait_for_optimiser, bool queue_baseline) {
  // Done as the current instances say it (PeerWatch): a done_t of an
  // optimiser killed and restarted since does not end the stream.
  const bool tracker_done = peers_.done("tracker");
  const bool optimiser_done = peers_.done("optimiser");
  const LifecycleTimes& lifecycle = ctx_.lifecycle();
  const bool optimiser_away = away("optimiser", lifecycle.peer_seen_s);
  const bool upstream_away = away("tracker", lifecycle.silence_s) && away("optimiser", lifecycle.silence_s);
  std::lock_guard<std::mutex> lock(mutex_);
  // A fresh mapper waits as before (rekon-replay stands in for both without heartbeats).
  const bool resumed = resumed_from_ > 0;  // a restart with frames in its store
  const bool optimiser_gone = resumed && optimiser_away;
  if (resumed && end_frame_ == kNoEndYet && upstream_away) {
    end_frame_ = resumed_from_ - 1;
    spdlog::warn("neither rekon-tracker nor rekon-optimiser is heard (lifecycle.silence_s = {:.1f} s): the run ended "
                 "while this mapper was dead; final pass on its store, up to frame {}",
                 lifecycle.silence_s, end_frame_);
    return true;
  }
  if (resendUnderWay()) return false;
  const bool frames_done = end_frame_ != kNoEndYet && (tracker_done || last_resolved_ >= end_frame_);
  if (end_frame_ != kNoEndYet && wait_for_optimiser && !optimiser_done && frames_done && optimiser_gone &&
      !std::exchange(optimiser_gone_said_, true)) {
    spdlog::warn("every frame is in and rekon-optimiser is gone (not heard within lifecycle.peer_seen_s = {:.1f} s "
                 "of this start, or silent): final pass on the last poses it sent",
                 lifecycle.peer_seen_s);
  }
  if (end_frame_ != kNoEndYet && (wait_for_optimiser ? optimiser_done || (frames_done && optimiser_gone) : frames_done)) {
    if (optimiser_done) spdlog::info("the optimiser is done");
    return true;
  }
  if (frames_done && queue_baseline && !baseline_queued_) {
    baseline_queued_ = true;
    queue_.push_back(BaselineWork{});  // after every frame's work
    work_ready_.notify_one();
  }
  return false;
}

void Inbox::logProgress() {
  std::lock_guard<std::mutex> lock(mutex_);  // the worker's copy: the mapper's own counters are its alone
  spdlog::info("mapper: {} frames fused into {} KF keyframes, {} re-integrations, {} frames queued", progress_.frames,
               progress_.kf_keyframes, progress_.reintegrations, queuedFrames());
}

void Inbox::publishLive() {
  std::lock_guard<std::mutex> lock(mutex_);
  ctx_.setLive("frames_fused", static_cast<double>(progress_.frames));
  ctx_.setLive("kf_keyframes", static_cast<double>(progress_.kf_keyframes));
  ctx_.setLive("reintegrations", static_cast<double>(progress_.reintegrations));
  ctx_.setLive("queued_frames", static_cast<double>(queuedFrames()));
  ctx_.setLive("frames_dropped", static_cast<double>(counts_.dropped_frames));
  ctx_.setLive("frames_dropped_when_full", static_cast<double>(counts_.dropped_when_full));
  // The voxel tiers in MiB (volume::kBlockVoxels voxels of 12 bytes a block).
  constexpr double kBlockMiB = volume::kBlockVoxels * sizeof(volume::Voxel) / 1048576.0;
  ctx_.setLive("voxels_active_mb", static_cast<double>(progress_.active_blocks) * kBlockMiB);
  ctx_.setLive("voxels_host_mb", static_cast<double>(progress_.host_blocks_in_memory) * kBlockMiB);
  ctx_.setLive("voxels_on_disk_mb", static_cast<double>(progress_.host_blocks_on_disk) * kBlockMiB);
}

void Inbox::drain() {
  std::unique_lock<std::mutex> lock(mutex_);
  idle_.wait(lock, [&] { return (queue_.empty() && !busy_) || !worker_error_.empty(); });
  stop_worker_ = true;
  work_ready_.notify_all();
}

void Inbox::dropUnjoinedFrames() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (images_.empty()) return;
  spdlog::warn("{} frames never got a tracked frame; dropped", images_.size());
  counts_.dropped_frames += static_cast<int64_t>(images_.size());
}

}  // namespace rekon::mapper
