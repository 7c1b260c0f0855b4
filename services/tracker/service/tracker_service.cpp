#include "tracker_service.hpp"

#include <spdlog/spdlog.h>
#include <time.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <mutex>
#include <thread>

#include "rekon/common/frame_transport.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/tracker/tracker.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::tracker {
namespace {

double threadCpuSeconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// Everything the bus thread's frame handler touches, behind one mutex so that
// the main thread can read the totals at the end.
struct ServiceState {
  std::mutex mutex;
  Tracker tracker;
  FrameReceiver receiver;
  Trajectory odometry;
  int64_t frames = 0, lost = 0, keyframes = 0, constraints = 0, undecodable = 0;
  double track_cpu_s = 0.0;
  explicit ServiceState(const TrackerParams& p) : tracker(p) {}
};

void publishResult(Bus& bus, const TrackResult& r) {
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
    bus.publish(channel::kKeyframes, kf);
  }
  if (r.odometry) {
    rekon_msgs::constraint_t c{};
    c.kind = rekon_msgs::constraint_t::KIND_ODOMETRY;
    c.from_id = r.odometry->from_id;
    c.to_id = r.odometry->to_id;
    c.relative = toMsg(r.odometry->relative);
    toArray(r.odometry->information, c.information);
    bus.publish(channel::kConstraints, c);
  }
  // After the keyframe and its constraint, so that a consumer meeting a new
  // keyframe id in a tracked frame already knows the keyframe.
  bus.publish(channel::kTrackedFrames, tf);
}

}  // namespace

void runTrackerService(ServiceContext& ctx) {
  const TrackerParams params = trackerParamsFromConfig(ctx.config());
  Bus& bus = ctx.bus();
  ServiceState state(params);
  std::atomic<int64_t> last_handled{-1};
  std::atomic<int64_t> end_frame{-2};  // -2: no end of stream yet

  bus.subscribe<rekon_msgs::end_of_stream_t>(channel::kEndOfStream, [&](const rekon_msgs::end_of_stream_t& m) {
    spdlog::info("end of stream after frame {} ({} frames)", m.last_frame_id, m.frames);
    end_frame.store(m.last_frame_id);
  });
  bus.subscribe<rekon_msgs::frame_t>(channel::kFrames, [&](const rekon_msgs::frame_t& msg) {
    {
      std::lock_guard<std::mutex> lock(state.mutex);
      Intrinsics k;
      std::optional<RgbdFrame> frame = state.receiver.receive(msg, &k);
      if (!frame) {
        ++state.undecodable;  // the receiver logged why; acknowledge so the source is not held up
      } else {
        const double t0 = threadCpuSeconds();
        const TrackResult r = state.tracker.track(*frame, k);
        state.track_cpu_s += threadCpuSeconds() - t0;
        ++state.frames;
        state.lost += r.state == TrackingState::Lost;
        state.keyframes += r.new_keyframe;
        state.constraints += r.odometry.has_value();
        state.odometry.push_back({r.timestamp, r.pose_world});
        if (r.state == TrackingState::Lost)
          spdlog::warn("frame {}: lost ({})", r.frame_id, toString(r.lost_reason));
        publishResult(bus, r);
      }
    }
    rekon_msgs::frame_ack_t ack{};
    ack.service = ctx.name();
    ack.frame_id = msg.frame_id;
    bus.publish(channel::kFrameAck, ack);
    ctx.setLastFrame(msg.frame_id);
    last_handled.store(msg.frame_id);
  });
  ctx.setState("running");
  spdlog::info("tracking levels {}..{}, keyframe criterion {}", params.aligner.coarsest_level,
               params.aligner.finest_level, params.keyframe.criterion);

  while (!ctx.stopRequested()) {
    const int64_t end = end_frame.load();
    if (end != -2 && last_handled.load() >= end) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ctx.setState("finishing");
  ctx.stopThreads();  // no handler runs after this

  const double n = static_cast<double>(std::max<int64_t>(state.frames, 1));
  ctx.stats()
      .set("frames", static_cast<long long>(state.frames))
      .set("lost_frames", static_cast<long long>(state.lost))
      .set("keyframes", static_cast<long long>(state.keyframes))
      .set("odometry_constraints", static_cast<long long>(state.constraints))
      .set("undecodable_frames", static_cast<long long>(state.undecodable))
      .set("track_cpu_ms_per_frame", 1e3 * state.track_cpu_s / n);
  if (!ctx.outDir().empty()) {
    const std::string path = (std::filesystem::path(ctx.outDir()) / "odometry.txt").string();
    writeTumTrajectory(state.odometry, path);
    spdlog::info("wrote {} odometry poses to {}", state.odometry.size(), path);
  }
  spdlog::info("tracked {} frames ({} lost), {} keyframes, {:.2f} ms CPU per frame", state.frames, state.lost,
               state.keyframes, 1e3 * state.track_cpu_s / n);
}

}  // namespace rekon::tracker
