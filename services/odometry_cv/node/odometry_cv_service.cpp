#include "odometry_cv_service.hpp"

#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <memory>
#include <mutex>
#include <thread>

#include "rekon/common/cpu_time.hpp"
#include "rekon/common/frame_ack.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/odometry_cv/cv_odometry.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::odometry_cv {
namespace {

// done_t and the final update go out this often, this far apart: UDP may drop one.
constexpr int kRepeats = 3;
constexpr auto kRepeatGap = std::chrono::milliseconds(50);

// Tracks each frame on the bus thread (the player's back-pressure paces it),
// publishing what the contract asks in its order.
class Frontend {
 public:
  explicit Frontend(ServiceContext& ctx) : ctx_(ctx) {}

  void subscribe() {
    ctx_.bus().subscribe<rekon_msgs::frame_t>(channel::kFrames, [this](const rekon_msgs::frame_t& m) { onFrame(m); });
    ctx_.bus().subscribe<rekon_msgs::end_of_stream_t>(
        channel::kEndOfStream, [this](const rekon_msgs::end_of_stream_t& m) { end_frame_.store(m.last_frame_id); });
  }

  void waitForEndOfStream() const {
    while (!ctx_.stopRequested()) {
      const int64_t end = end_frame_.load();
      if (end != kNoEndYet && last_handled_.load() >= end) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }

  // The final graph update, done_t as tracker and optimiser, trajectory.txt and the stats.
  void finish() {
    std::lock_guard<std::mutex> lock(mutex_);
    for (int i = 0; i < kRepeats && odometry_; ++i) {
      if (i > 0) std::this_thread::sleep_for(kRepeatGap);
      ctx_.bus().publish(channel::kGraphUpdates, graphUpdate(true));
    }
    for (int i = 0; i < kRepeats; ++i) {
      std::this_thread::sleep_for(kRepeatGap);
      ctx_.bus().publish(channel::kDone, doneMessage("tracker", end_frame_.load()));
      ctx_.bus().publish(channel::kDone, doneMessage("optimiser", end_frame_.load()));
    }
    if (!ctx_.outDir().empty()) {
      writeTumTrajectory(trajectory_, (std::filesystem::path(ctx_.outDir()) / "trajectory.txt").string());
      spdlog::info("wrote {} frame poses to {}/trajectory.txt", trajectory_.size(), ctx_.outDir());
    }
    const double ms = frames_ > 0 ? cpu_ms_ / static_cast<double>(frames_) : 0.0;
    const size_t keyframes = odometry_ ? odometry_->keyframes().size() : 0;
    ctx_.stats()
        .set("frames", static_cast<long long>(frames_))
        .set("keyframes", keyframes)
        .set("lost_frames", static_cast<long long>(lost_))
        .set("track_cpu_ms_mean", ms);
    spdlog::info("{} frames, {} keyframes, {} lost, {:.2f} ms CPU per frame", frames_, keyframes, lost_, ms);
  }

 private:
  static constexpr int64_t kNoEndYet = -2;

  rekon_msgs::graph_update_t graphUpdate(bool final_update) const {
    rekon_msgs::graph_update_t u{};
    // One per keyframe, then the final one after them: increasing.
    u.version = static_cast<int64_t>(odometry_->keyframes().size()) + (final_update ? 1 : 0);
    u.final_update = final_update;
    for (const auto& [id, pose] : odometry_->keyframes()) {
      u.keyframe_ids.push_back(id);
      u.poses.push_back(toMsg(pose));
    }
    u.num_keyframes = static_cast<int32_t>(u.keyframe_ids.size());
    return u;
  }

  void onFrame(const rekon_msgs::frame_t& msg) {
    std::lock_guard<std::mutex> lock(mutex_);
    Intrinsics k;
    if (const auto frame = receiver_.receive(msg, &k)) track(*frame, k);
    acknowledgeFrame(ctx_, msg.frame_id);
    last_handled_.store(msg.frame_id);
  }

  void track(const RgbdFrame& frame, const Intrinsics& k) {
    if (!odometry_) odometry_ = std::make_unique<CvOdometry>(k);
    const double start = threadCpuMs();
    const CvTracked t = odometry_->track(frame.depth, frame.color);
    cpu_ms_ += threadCpuMs() - start;
    ++frames_;
    if (t.new_keyframe) {
      rekon_msgs::keyframe_t kf{};
      kf.keyframe_id = t.keyframe_id;
      kf.frame_id = frame.id;
      kf.timestamp = frame.timestamp;
      kf.pose_world = toMsg(t.keyframe_world);
      ctx_.bus().publish(channel::kKeyframes, kf);
    }
    rekon_msgs::tracked_frame_t tf{};
    tf.frame_id = frame.id;
    tf.timestamp = frame.timestamp;
    tf.keyframe_id = t.keyframe_id;
    tf.pose_in_keyframe = toMsg(t.pose_in_keyframe);
    toArray(t.covariance, tf.covariance);
    tf.state = t.lost ? rekon_msgs::tracked_frame_t::STATE_LOST : rekon_msgs::tracked_frame_t::STATE_OK;
    ctx_.bus().publish(channel::kTrackedFrames, tf);
    if (t.new_keyframe) ctx_.bus().publish(channel::kGraphUpdates, graphUpdate(false));
    lost_ += t.lost;
    if (!t.lost) trajectory_.push_back({frame.timestamp, orthonormalised(t.keyframe_world * t.pose_in_keyframe)});
  }

  ServiceContext& ctx_;
  std::mutex mutex_;
  FrameReceiver receiver_;
  std::unique_ptr<CvOdometry> odometry_;
  Trajectory trajectory_;
  int64_t frames_ = 0, lost_ = 0;
  double cpu_ms_ = 0.0;
  std::atomic<int64_t> last_handled_{-1}, end_frame_{kNoEndYet};
};

}  // namespace

void runOdometryCvService(ServiceContext& ctx) {
  Frontend frontend(ctx);
  StopThreadsOnExit stop_threads(ctx);  // before `frontend` dies: the bus handlers use it
  frontend.subscribe();
  ctx.setState("running");
  frontend.waitForEndOfStream();
  if (ctx.stopRequested()) return;
  ctx.setState("finishing");
  frontend.finish();
}

}  // namespace rekon::odometry_cv
