#include "replay_service.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/common/frame_ack.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/replay/replay.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::replay {
namespace {

// As the optimiser: the last update and done may be dropped by UDP, so thrice.
constexpr int kDoneRepeats = 3;
constexpr auto kDoneGap = std::chrono::milliseconds(50);

// --odometry-sigma T,R: the diagonal information of the odometry edges, or
// nullopt without the option (the replay is then tracker and optimiser).
std::optional<Eigen::Matrix<double, 6, 6>> odometryInformation(const ArgParser& args) {
  if (!args.has("odometry-sigma")) return std::nullopt;
  double t = 0, r = 0;
  char end = 0;
  if (std::sscanf(args.get("odometry-sigma").c_str(), "%lf,%lf%c", &t, &r, &end) != 2 || !(t > 0) || !(r > 0))
    throw Error("--odometry-sigma needs T,R: two positive standard deviations (metres, radians), got \"" +
                args.get("odometry-sigma") + "\"");
  Eigen::Matrix<double, 6, 6> info = Eigen::Matrix<double, 6, 6>::Zero();
  info.diagonal() << 1 / (t * t), 1 / (t * t), 1 / (t * t), 1 / (r * r), 1 / (r * r), 1 / (r * r);
  return info;
}

ReplayParams paramsFromArgs(const ArgParser& args) {
  ReplayParams p;
  p.trajectory = args.get("trajectory");
  p.target = args.has("odometry-sigma") && !args.has("target") ? p.trajectory : args.get("target");
  p.update_every_keyframes = args.getInt("update-every");
  p.stream_alpha = args.getDouble("stream-alpha");
  p.final_updates = args.getInt("final-updates");
  p.validate();
  return p;
}

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

// The frame's new keyframe, if it starts one, then the tracked frame, as the tracker sends them.
void publishTracked(Bus& bus, const ReplayTracked& t) {
  if (t.new_keyframe_world) {
    rekon_msgs::keyframe_t kf{};
    kf.keyframe_id = t.keyframe_id;
    kf.frame_id = t.frame_id;
    kf.timestamp = t.timestamp;
    kf.pose_world = toMsg(*t.new_keyframe_world);
    bus.publish(channel::kKeyframes, kf);
  }
  rekon_msgs::tracked_frame_t tf{};
  tf.frame_id = t.frame_id;
  tf.timestamp = t.timestamp;
  tf.keyframe_id = t.keyframe_id;
  tf.pose_in_keyframe = toMsg(t.pose_in_keyframe);
  toArray(Eigen::Matrix<double, 6, 6>::Identity() * 1e-6, tf.covariance);
  tf.state = t.lost ? rekon_msgs::tracked_frame_t::STATE_LOST : rekon_msgs::tracked_frame_t::STATE_OK;
  bus.publish(channel::kTrackedFrames, tf);
}

void publishDone(Bus& bus, const std::string& service, int64_t last_frame) {
  bus.publish(channel::kDone, doneMessage(service, last_frame));
}

// The script driven by the frames the player announces (on the bus thread);
// the main thread finishes it after the end of stream.
class ScriptedFrontend {
 public:
  ScriptedFrontend(ServiceContext& ctx, ReplayScript& script,
                   std::optional<Eigen::Matrix<double, 6, 6>> odometry_information)
      : ctx_(ctx), script_(script), odometry_information_(std::move(odometry_information)) {}

  void subscribe() {
    ctx_.bus().subscribe<rekon_msgs::end_of_stream_t>(
        channel::kEndOfStream, [this](const rekon_msgs::end_of_stream_t& m) { end_frame_.store(m.last_frame_id); });
    ctx_.bus().subscribe<rekon_msgs::frame_t>(channel::kFrames, [this](const rekon_msgs::frame_t& m) { onFrame(m); });
  }

  // Until every frame up to the end of stream is answered, or a stop request.
  void waitForEndOfStream() const {
    while (!ctx_.stopRequested()) {
      const int64_t end = end_frame_.load();
      if (end != kNoEndYet && last_handled_.load() >= end) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }

  // done_t for the tracker, the final updates `gap_ms` apart, then done_t for the optimiser.
  void finish(int gap_ms) {
    std::lock_guard<std::mutex> lock(mutex_);
    publishDone(ctx_.bus(), "tracker", end_frame_.load());
    if (odometry_information_) {  // the optimiser is rekon-optimiser: it must not miss this done_t
      for (int i = 1; i < kDoneRepeats; ++i) {
        std::this_thread::sleep_for(kDoneGap);
        publishDone(ctx_.bus(), "tracker", end_frame_.load());
      }
      spdlog::info("replay: {} DVO keyframes and their odometry constraints", keyframes_);
      ctx_.stats().set("keyframes", static_cast<long long>(keyframes_));
      return;
    }
    for (const ReplayGraphUpdate& u : script_.finalUpdates()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(gap_ms));
      publishUpdate(ctx_.bus(), u);
      ++updates_;
    }
    for (int i = 0; i < kDoneRepeats; ++i) {
      std::this_thread::sleep_for(kDoneGap);
      publishDone(ctx_.bus(), "optimiser", end_frame_.load());
    }
    ctx_.stats().set("keyframes", static_cast<long long>(keyframes_)).set("graph_updates", static_cast<long long>(updates_))
        .set("lost_frames", static_cast<long long>(lost_));
    spdlog::info("replay: {} DVO keyframes, {} graph updates, {} frames without a pose", keyframes_, updates_, lost_);
  }

 private:
  static constexpr int64_t kNoEndYet = -2;

  void onFrame(const rekon_msgs::frame_t& msg) {
    std::lock_guard<std::mutex> lock(mutex_);
    const ReplayTracked t = script_.onFrame(msg.frame_id, msg.timestamp);
    publishTracked(ctx_.bus(), t);
    keyframes_ += t.new_keyframe_world.has_value();
    lost_ += t.lost;
    if (odometry_information_) publishOdometry(t);
    else if (auto u = script_.dueUpdate()) {
      publishUpdate(ctx_.bus(), *u);
      ++updates_;
    }
    acknowledgeFrame(ctx_, msg.frame_id);
    last_handled_.store(msg.frame_id);
  }

  // The edge from the previous keyframe to the one this frame starts.
  void publishOdometry(const ReplayTracked& t) {
    if (!t.new_keyframe_world) return;
    if (last_keyframe_) {
      rekon_msgs::constraint_t c{};
      c.kind = rekon_msgs::constraint_t::KIND_ODOMETRY;
      c.from_id = last_keyframe_->first;
      c.to_id = t.keyframe_id;
      c.relative = toMsg(orthonormalised(last_keyframe_->second.inverse() * *t.new_keyframe_world));
      toArray(*odometry_information_, c.information);
      ctx_.bus().publish(channel::kConstraints, c);
    }
    last_keyframe_ = {t.keyframe_id, *t.new_keyframe_world};
  }

  ServiceContext& ctx_;
  ReplayScript& script_;
  const std::optional<Eigen::Matrix<double, 6, 6>> odometry_information_;
  std::optional<std::pair<int64_t, Pose>> last_keyframe_;
  std::mutex mutex_;
  std::atomic<int64_t> last_handled_{-1}, end_frame_{kNoEndYet};
  int64_t keyframes_ = 0, updates_ = 0, lost_ = 0;
};

}  // namespace

void runReplayService(ServiceContext& ctx) {
  const ReplayParams p = paramsFromArgs(ctx.args());
  const Trajectory source = readTumTrajectory(p.trajectory);
  const int max_frames = ctx.config().getInt("player.max_frames");
  const int64_t total = max_frames > 0 ? std::min<int64_t>(max_frames, static_cast<int64_t>(source.size()))
                                       : static_cast<int64_t>(source.size());
  ReplayScript script(source, readTumTrajectory(p.target), p, total);
  const int gap_ms = ctx.args().getInt("gap-ms");
  ScriptedFrontend frontend(ctx, script, odometryInformation(ctx.args()));
  StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
  frontend.subscribe();
  ctx.setState("running");
  spdlog::info("replaying {} toward {}", p.trajectory, p.target);
  frontend.waitForEndOfStream();
  if (ctx.stopRequested()) return;
  ctx.setState("finishing");
  frontend.finish(gap_ms);
}

}  // namespace rekon::replay
