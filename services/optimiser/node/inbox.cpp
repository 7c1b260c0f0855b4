#include "inbox.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <string>
#include <utility>

#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::optimiser {

Inbox::Inbox(ServiceContext& ctx, double information_scale) : ctx_(ctx), information_scale_(information_scale) {}

void Inbox::subscribe(PeerWatch& peers) {
  Bus& bus = ctx_.bus();
  auto onKeyframe = [this](const rekon_msgs::keyframe_t& m) {
    try {
      queue(keyframeFromMsg(m));
    } catch (const Error& e) {
      reject(e);
    }
  };
  auto onConstraint = [this](const rekon_msgs::constraint_t& m) {
    try {
      queue(constraintFromMsg(m, information_scale_));
    } catch (const Error& e) {
      reject(e);
    }
  };
  bus.subscribe<rekon_msgs::keyframe_t>(channel::kKeyframes, onKeyframe);
  bus.subscribe<rekon_msgs::keyframe_t>(channel::kKeyframesResent, onKeyframe);
  bus.subscribe<rekon_msgs::constraint_t>(channel::kConstraints, onConstraint);
  bus.subscribe<rekon_msgs::constraint_t>(channel::kConstraintsResent, onConstraint);
  bus.subscribe<rekon_msgs::external_constraint_t>(kExternalConstraintsChannel,
                                                 [this](const rekon_msgs::external_constraint_t& m) {
                                                   try {
                                                     ExternalConstraint e = externalConstraintFromMsg(m);
                                                     {
                                                       std::lock_guard<std::mutex> lock(mutex_);
                                                       externals_.push_back(std::move(e));
                                                     }
                                                     wake_.notify_one();
                                                     ctx_.bus().publish(kExternalConstraintsAckChannel, m);
                                                   } catch (const Error& e) {
                                                     reject(e);
                                                   }
                                                 });
  bus.subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFrames, [this](const rekon_msgs::tracked_frame_t& m) {
    onTrackedFrame(m);
    ctx_.setLastFrame(m.frame_id);
  });
  bus.subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFramesResent,
                                             [this](const rekon_msgs::tracked_frame_t& m) { onTrackedFrame(m); });
  bus.subscribe<rekon_msgs::replay_end_t>(channel::kReplayEnd, [this](const rekon_msgs::replay_end_t& m) {
    if (m.service != ctx_.name() || m.pid != getpid()) return;  // another requester's, or a killed instance's
    {
      std::lock_guard<std::mutex> lock(mutex_);
      replay_end_ = m;
    }
    wake_.notify_one();
  });
  bus.subscribe<rekon_msgs::done_t>(channel::kDone, [this](const rekon_msgs::done_t& m) {
    if (m.service != kUpstreamService) return;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (upstream_done_) return;  // done_t is sent several times
      upstream_done_ = true;
    }
    spdlog::info("{} is done (last frame {}): final optimisation", m.service, m.last_frame_id);
    wake_.notify_one();
  });
  peers.onNewInstance([this](const std::string& service, int instance) {
    if (service != "mapper") return;
    spdlog::warn("rekon-mapper restarted (instance {})", instance);
    std::lock_guard<std::mutex> lock(mutex_);
    mapper_restarted_ = true;
  });
}

void Inbox::reject(const Error& e) {
  spdlog::error("{}", e.what());
  std::lock_guard<std::mutex> lock(mutex_);
  ++rejected_;
}

void Inbox::queue(GraphItem item) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    graph_items_.push_back(std::move(item));
  }
  wake_.notify_one();
}

void Inbox::onTrackedFrame(const rekon_msgs::tracked_frame_t& m) {
  try {
    TrackedFrame f = trackedFrameFromMsg(m);
    std::lock_guard<std::mutex> lock(mutex_);
    if (frame_ids_.insert(f.frame_id)) {
      if (hold_frames_) held_frames_.emplace(f.frame_id, f);
      new_frames_.push_back(f);
    }
    last_frame_id_ = std::max(last_frame_id_, f.frame_id);
  } catch (const Error& e) {
    reject(e);
  }
}

std::vector<GraphItem> Inbox::waitForGraphItems(std::chrono::milliseconds timeout, bool* upstream_done) {
  std::vector<GraphItem> items;
  std::unique_lock<std::mutex> lock(mutex_);
  wake_.wait_for(lock, timeout, [&] { return !graph_items_.empty() || !externals_.empty() || upstream_done_; });
  items.swap(graph_items_);
  *upstream_done = upstream_done_;
  return items;
}

std::vector<GraphItem> Inbox::takeGraphItems() {
  std::vector<GraphItem> items;
  std::lock_guard<std::mutex> lock(mutex_);
  items.swap(graph_items_);
  return items;
}

std::vector<ExternalConstraint> Inbox::takeExternalConstraints() {
  std::vector<ExternalConstraint> out;
  std::lock_guard<std::mutex> lock(mutex_);
  out.swap(externals_);
  return out;
}

std::optional<rekon_msgs::replay_end_t> Inbox::waitForReplayEnd(int64_t request_id, Clock::time_point deadline) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (wake_.wait_until(lock, deadline, [&] { return replay_end_ && replay_end_->request_id == request_id; }))
    return replay_end_;
  return std::nullopt;
}

void Inbox::setUpstreamDone() {
  std::lock_guard<std::mutex> lock(mutex_);
  upstream_done_ = true;
}

std::vector<TrackedFrame> Inbox::takeNewFrames() {
  std::vector<TrackedFrame> out;
  std::lock_guard<std::mutex> lock(mutex_);
  out.swap(new_frames_);
  return out;
}

void Inbox::restoreFrames(const std::vector<TrackedFrame>& frames) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const TrackedFrame& f : frames) {
    if (frame_ids_.insert(f.frame_id) && hold_frames_) held_frames_.emplace(f.frame_id, f);
    last_frame_id_ = std::max(last_frame_id_, f.frame_id);
  }
}

size_t Inbox::trackedFrameCount() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return frame_ids_.size();
}

int64_t Inbox::lastFrameId() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_frame_id_;
}

bool Inbox::takeMapperRestarted() {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::exchange(mapper_restarted_, false);
}

Inbox::Final Inbox::takeFinal() {
  Final out;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [id, f] : held_frames_) out.frames.push_back(f);
  out.last_frame_id = last_frame_id_;
  out.rejected = rejected_;
  mapper_restarted_ = false;
  return out;
}

}  // namespace rekon::optimiser
