#include "replay_service.hpp"

#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/replay/replay.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::replay {
namespace {

void publishUpdate(Bus& bus, const ReplayGraphUpdate& u) {
  rekon_msgs::graph_update_t m{};
  m.version = u.version;
  m.final_update = u.final_update;
  m.num_keyframes = static_cast<int32_t>(u.poses.size());
  for (const auto& [id, pose] : u.poses) {
    m.keyframe_ids.push_back(id);
    m.poses.push_back(toMsg(pose));
  }
  bus.publish(channel::kGraphUpdates, m);
}

void publishDone(Bus& bus, const std::string& service, int64_t last_frame) {
  rekon_msgs::done_t d{};
  d.service = service;
  d.last_frame_id = last_frame;
  bus.publish(channel::kDone, d);
}

}  // namespace

void runReplayService(ServiceContext& ctx) {
  ReplayParams p;
  p.trajectory = ctx.args().get("trajectory");
  p.target = ctx.args().get("target");
  p.update_every_keyframes = ctx.args().getInt("update-every");
  p.stream_alpha = ctx.args().getDouble("stream-alpha");
  p.final_updates = ctx.args().getInt("final-updates");
  p.validate();
  const Trajectory source = readTumTrajectory(p.trajectory);
  const int max_frames = ctx.config().getInt("player.max_frames");
  const int64_t total = max_frames > 0 ? std::min<int64_t>(max_frames, static_cast<int64_t>(source.size()))
                                       : static_cast<int64_t>(source.size());
  ReplayScript script(source, readTumTrajectory(p.target), p, total);
  const int gap_ms = ctx.args().getInt("gap-ms");
  Bus& bus = ctx.bus();
  std::mutex mutex;
  std::atomic<int64_t> last_handled{-1}, end_frame{-2};
  int64_t keyframes = 0, updates = 0, lost = 0;

  StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
  bus.subscribe<rekon_msgs::end_of_stream_t>(channel::kEndOfStream,
                                             [&](const rekon_msgs::end_of_stream_t& m) { end_frame.store(m.last_frame_id); });
  bus.subscribe<rekon_msgs::frame_t>(channel::kFrames, [&](const rekon_msgs::frame_t& msg) {
    std::lock_guard<std::mutex> lock(mutex);
    const ReplayTracked t = script.onFrame(msg.frame_id, msg.timestamp);
    if (t.new_keyframe_world) {
      rekon_msgs::keyframe_t kf{};
      kf.keyframe_id = t.keyframe_id;
      kf.frame_id = t.frame_id;
      kf.timestamp = t.timestamp;
      kf.pose_world = toMsg(*t.new_keyframe_world);
      bus.publish(channel::kKeyframes, kf);
      ++keyframes;
    }
    rekon_msgs::tracked_frame_t tf{};
    tf.frame_id = t.frame_id;
    tf.timestamp = t.timestamp;
    tf.keyframe_id = t.keyframe_id;
    tf.pose_in_keyframe = toMsg(t.pose_in_keyframe);
    toArray(Eigen::Matrix<double, 6, 6>::Identity() * 1e-6, tf.covariance);
    tf.state = t.lost ? rekon_msgs::tracked_frame_t::STATE_LOST : rekon_msgs::tracked_frame_t::STATE_OK;
    lost += t.lost;
    bus.publish(channel::kTrackedFrames, tf);
    if (auto u = script.dueUpdate()) {
      publishUpdate(bus, *u);
      ++updates;
    }
    rekon_msgs::frame_ack_t ack{};
    ack.service = ctx.name();
    ack.frame_id = msg.frame_id;
    bus.publish(channel::kFrameAck, ack);
    ctx.setLastFrame(msg.frame_id);
    last_handled.store(msg.frame_id);
  });
  ctx.setState("running");
  spdlog::info("replaying {} toward {}", p.trajectory, p.target);
  while (!ctx.stopRequested()) {
    const int64_t end = end_frame.load();
    if (end != -2 && last_handled.load() >= end) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  if (ctx.stopRequested()) return;
  ctx.setState("finishing");
  std::lock_guard<std::mutex> lock(mutex);
  publishDone(bus, "tracker", end_frame.load());
  for (const ReplayGraphUpdate& u : script.finalUpdates()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(gap_ms));
    publishUpdate(bus, u);
    ++updates;
  }
  // As the optimiser: its last update and done may be dropped by UDP, so thrice.
  for (int i = 0; i < 3; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    publishDone(bus, "optimiser", end_frame.load());
  }
  ctx.stats().set("keyframes", static_cast<long long>(keyframes)).set("graph_updates", static_cast<long long>(updates))
      .set("lost_frames", static_cast<long long>(lost));
  spdlog::info("replay: {} DVO keyframes, {} graph updates, {} frames without a pose", keyframes, updates, lost);
}

}  // namespace rekon::replay
