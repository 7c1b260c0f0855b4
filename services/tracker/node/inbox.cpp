#include "inbox.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <string>
#include <unordered_map>
#include <utility>

#include "rekon/common/error.hpp"
#include "rekon/common/frame_ack.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/common/pose.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/replay_request_t.hpp"
#include "rekon_msgs/resume_point_t.hpp"

namespace rekon::tracker {

Inbox::Inbox(ServiceContext& ctx, TrackingWorker& worker, History& history, LoopClosureWorker& loops,
             bool hold_when_behind)
    : ctx_(ctx), worker_(worker), history_(history), loops_(loops), hold_when_behind_(hold_when_behind) {}

void Inbox::subscribe() {
  Bus& bus = ctx_.bus();
  // A restarted mapper announces its resume point before it runs, and the
  // player sends frames again on it: the tracker learns of the new instance
  // from the same message, never after those frames.
  const auto note_mapper = [this](int pid) {
    if (history_.noteMapperPid(pid)) spdlog::warn("rekon-mapper restarted (pid {}): frames sent again get their results again", pid);
  };
  bus.subscribe<rekon_msgs::resume_point_t>(channel::kResumePoint, [note_mapper](const rekon_msgs::resume_point_t& m) {
    if (m.service == "mapper") note_mapper(m.pid);
  });
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [note_mapper](const rekon_msgs::heartbeat_t& m) {
    if (m.service == "mapper" && m.state == "running") note_mapper(m.pid);
  });
  bus.subscribe<rekon_msgs::replay_request_t>(channel::kReplayRequest, [this](const rekon_msgs::replay_request_t& m) {
    spdlog::debug("rekon-{} (pid {}) asks for a replay", m.service, m.pid);  // every optimiser does at its end
    history_.addReplayRequest(m);
  });
  bus.subscribe<rekon_msgs::graph_update_t>(channel::kGraphUpdates,
                                            [this](const rekon_msgs::graph_update_t& m) { onGraphUpdate(m); });
  bus.subscribe<rekon_msgs::end_of_stream_t>(channel::kEndOfStream,
                                             [this](const rekon_msgs::end_of_stream_t& m) { onEndOfStream(m); });
  bus.subscribe<rekon_msgs::frame_t>(channel::kFrames, [this](const rekon_msgs::frame_t& m) { onFrame(m); });
}

double Inbox::secondsSinceLastFrame() const {
  const auto t = Clock::time_point(Clock::duration(last_frame_at_.load()));
  return std::chrono::duration<double>(Clock::now() - t).count();
}

void Inbox::resumeFrom(int64_t first_missing, double rewind_wait_s) {
  if (first_missing < 0) return;
  rewind_wait_s_ = rewind_wait_s;
  last_handled_.store(first_missing - 1);
  resume_from_ = first_missing;
  resume_since_ = Clock::now();
}

void Inbox::onFrame(const rekon_msgs::frame_t& msg) {
  last_frame_at_.store(Clock::now().time_since_epoch().count());
  if (resume_from_ >= 0 && msg.frame_id > resume_from_) {
    if (std::chrono::duration<double>(Clock::now() - resume_since_).count() < rewind_wait_s_) {
      ++before_resume_;
      return;
    }
    spdlog::warn("the frame source did not rewind to frame {} within {} s; going on from frame {} (frames {}..{} are "
                 "not tracked)",
                 resume_from_, rewind_wait_s_, msg.frame_id, resume_from_, msg.frame_id - 1);
  }
  if (msg.frame_id >= resume_from_) resume_from_ = -1;
  bool tracked = false;
  if (msg.frame_id <= last_handled_.load()) {
    // Sent again: for a restarted mapper, or because its acknowledgement was lost.
    ++duplicates_;
    if (!history_.republishResult(msg.frame_id))
      spdlog::warn("frame {} came again but was never tracked (lost on its first way); skipped", msg.frame_id);
  } else {
    tracked = worker_.track(msg);  // a frame that does not decode is acknowledged all the same: the source goes on
    publishLive();
  }
  acknowledge(msg.frame_id);
  // Only a tracked frame moves the mark: a rejected one with a huge id would
  // make every later frame a duplicate and end the stream early.
  if (tracked && msg.frame_id > last_handled_.load()) {
    ctx_.setLastFrame(msg.frame_id);
    last_handled_.store(msg.frame_id);
  }
}

void Inbox::acknowledge(int64_t frame_id) {
  std::lock_guard<std::mutex> lock(ack_mutex_);
  if (!hold_when_behind_ || !loops_.behind()) return sendAckLocked(frame_id);
  if (held_ack_ < 0) held_since_ = Clock::now();
  held_ack_ = std::max(held_ack_, frame_id);
}

void Inbox::releaseHeldAck() {
  std::lock_guard<std::mutex> lock(ack_mutex_);
  if (held_ack_ >= 0 && !loops_.behind()) sendAckLocked(held_ack_);
}

void Inbox::sendAckLocked(int64_t frame_id) {
  if (held_ack_ >= 0) {
    held_s_ += std::chrono::duration<double>(Clock::now() - held_since_).count();
    frame_id = std::max(frame_id, held_ack_);  // acknowledgements are cumulative
    held_ack_ = -1;
  }
  publishFrameAck(ctx_, frame_id);
}

double Inbox::ackHeldSeconds() const {
  std::lock_guard<std::mutex> lock(ack_mutex_);
  return held_s_;
}

void Inbox::publishLive() {
  const TrackingCounts n = worker_.counts();
  ctx_.setLive("frames", static_cast<double>(n.frames));
  ctx_.setLive("lost_frames", static_cast<double>(n.lost));
  ctx_.setLive("keyframes", static_cast<double>(n.keyframes));
  ctx_.setLive("loop_closures_accepted", static_cast<double>(loops_.stats().accepted));
  const KeyframeCacheStats kf = loops_.keyframeCacheStats();
  ctx_.setLive("keyframes_in_memory", static_cast<double>(kf.resident));
  ctx_.setLive("keyframes_on_disk", static_cast<double>(kf.keyframes - kf.resident));
}

void Inbox::onGraphUpdate(const rekon_msgs::graph_update_t& m) {
  history_.noteGraphVersion(m.version);
  std::unordered_map<int64_t, Pose> poses;
  try {
    for (const auto& [id, pose] : graphPoses(m)) poses.emplace(id, pose);
  } catch (const Error& e) {
    spdlog::error("{}", e.what());
    return;
  }
  worker_.updateGraph(m.version, std::move(poses));  // older versions are ignored there
}

void Inbox::onEndOfStream(const rekon_msgs::end_of_stream_t& m) {
  spdlog::info("end of stream after frame {} ({} frames)", m.last_frame_id, m.frames);
  end_frame_.store(m.last_frame_id);
}

}  // namespace rekon::tracker
