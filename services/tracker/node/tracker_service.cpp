#include "tracker_service.hpp"

#include <spdlog/spdlog.h>
#include <time.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

#include "rekon/common/cpu_time.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/tracker.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/replay_end_t.hpp"
#include "rekon_msgs/replay_request_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::tracker {
namespace {


// Everything the bus thread's frame handler touches, behind one mutex so that
// the main thread can read the totals at the end.
struct ServiceState {
  std::mutex mutex;
  Tracker tracker;
  FrameReceiver receiver;
  Trajectory odometry;
  int64_t frames = 0, lost = 0, keyframes = 0, constraints = 0, undecodable = 0;
  double track_cpu_s = 0.0;
  std::vector<std::pair<int64_t, double>> frame_ms;  // wall time of track() (pyramid included) per frame
  explicit ServiceState(const TrackerParams& p) : tracker(p) {}
};

// Everything the tracker has published that a consumer may need again: a
// restarted optimiser rebuilds its graph from a replay of it, and a frame the
// player sends again (for a restarted mapper) gets its stored result instead
// of being tracked twice. Written by the bus thread and the loop-closure
// worker; replayed from the main thread.
struct History {
  std::mutex mutex;
  std::vector<rekon_msgs::keyframe_t> keyframes;
  std::vector<rekon_msgs::constraint_t> constraints;  // odometry and loop edges, in publication order
  std::map<int64_t, rekon_msgs::tracked_frame_t> tracked;  // by frame id
  std::map<int64_t, rekon_msgs::keyframe_t> keyframe_of_frame;
  // Which mapper instance (1, then 2... after restarts) each frame's result
  // went out to: a frame sent again goes out again only to a newer instance,
  // so that a frame re-sent for a lost acknowledgement is not fused twice.
  int mapper_instance = 1;
  std::map<int64_t, int> published_for;
  int64_t graph_version = -1;
  bool done = false;
  std::vector<rekon_msgs::replay_request_t> requests;  // waiting for the main thread
};

// A replay is paced (a pause after every kReplayBurst messages) so that no
// receiver's socket buffer overflows on a loaded machine.
constexpr int kReplayBurst = 20;
constexpr auto kReplayPause = std::chrono::milliseconds(2);
// After the end of stream, a frame that has not come within this long was
// lost on the way (message loss): the tracker finishes without it.
constexpr double kLastFrameGraceS = 3.0;

// Done_t is sent this many times, this far apart: UDP multicast may drop one,
// and the optimiser's final optimisation waits for it.
constexpr int kDoneRepeats = 3;
constexpr auto kDoneGap = std::chrono::milliseconds(50);
// How often the end-of-stream wait looks at the stop flag.
constexpr int kDrainPollMs = 100;

void publishLoopConstraint(Bus& bus, History& history, const LoopConstraint& l) {
  rekon_msgs::constraint_t c{};
  c.kind = rekon_msgs::constraint_t::KIND_LOOP;
  c.from_id = l.from_id;
  c.to_id = l.to_id;
  c.relative = toMsg(l.relative);
  toArray(l.information, c.information);
  {
    std::lock_guard<std::mutex> lock(history.mutex);
    history.constraints.push_back(c);
  }
  bus.publish(channel::kConstraints, c);
  spdlog::info("loop closure {} -> {} (ln det ratios coarse {:.2f}, fine {:.2f}, {} pixels)", l.from_id, l.to_id,
               l.coarse_ratio, l.fine_ratio, l.valid_pixels);
}

double percentile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  const size_t i = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size()))) - 1;
  const size_t k = std::min(i, values.size() - 1);
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

void writeTiming(const std::vector<std::pair<int64_t, double>>& frame_ms, const std::string& path) {
  std::ofstream out(path);
  out << "frame_id,ms\n";
  for (const auto& [id, ms] : frame_ms) out << id << ',' << ms << '\n';
  if (!out) throw Error("cannot write " + path + "; check that the output folder is writable");
}

void publishResult(Bus& bus, History& history, const TrackResult& r) {
  std::lock_guard<std::mutex> lock(history.mutex);
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
    history.keyframes.push_back(kf);
    history.keyframe_of_frame[r.frame_id] = kf;
    bus.publish(channel::kKeyframes, kf);
  }
  if (r.odometry) {
    rekon_msgs::constraint_t c{};
    c.kind = rekon_msgs::constraint_t::KIND_ODOMETRY;
    c.from_id = r.odometry->from_id;
    c.to_id = r.odometry->to_id;
    c.relative = toMsg(r.odometry->relative);
    toArray(r.odometry->information, c.information);
    history.constraints.push_back(c);
    bus.publish(channel::kConstraints, c);
  }
  // After the keyframe and its constraint, so that a consumer meeting a new
  // keyframe id in a tracked frame already knows the keyframe.
  history.tracked[r.frame_id] = tf;
  history.published_for[r.frame_id] = history.mapper_instance;
  bus.publish(channel::kTrackedFrames, tf);
}

// A frame sent again (the player rewinds for a restarted mapper): its stored
// result goes out again on the live channels, keyframe first as before, when
// the mapper has restarted since it went out. The optimiser ignores what it
// already has. False when the frame was never tracked (it was lost on its
// first way): tracking it now, out of order, would corrupt the odometry.
bool republishResult(Bus& bus, History& history, int64_t frame_id) {
  std::lock_guard<std::mutex> lock(history.mutex);
  auto tf = history.tracked.find(frame_id);
  if (tf == history.tracked.end()) return false;
  int& published_for = history.published_for[frame_id];
  if (published_for >= history.mapper_instance) return true;
  published_for = history.mapper_instance;
  if (auto kf = history.keyframe_of_frame.find(frame_id); kf != history.keyframe_of_frame.end())
    bus.publish(channel::kKeyframes, kf->second);
  bus.publish(channel::kTrackedFrames, tf->second);
  return true;
}

// Answers the waiting replay requests: every keyframe, then every constraint
// (so that each edge's keyframes come first), then every tracked frame, on
// the *_RESENT channels, and a replay_end_t with the totals.
void serveReplays(Bus& bus, History& history) {
  std::vector<rekon_msgs::replay_request_t> requests;
  std::vector<rekon_msgs::keyframe_t> keyframes;
  std::vector<rekon_msgs::constraint_t> constraints;
  std::vector<rekon_msgs::tracked_frame_t> tracked;
  rekon_msgs::replay_end_t end{};
  {
    std::lock_guard<std::mutex> lock(history.mutex);
    if (history.requests.empty()) return;
    requests.swap(history.requests);
    keyframes = history.keyframes;
    constraints = history.constraints;
    for (const auto& [id, tf] : history.tracked) tracked.push_back(tf);
    end.keyframes = static_cast<int64_t>(keyframes.size());
    end.constraints = static_cast<int64_t>(constraints.size());
    end.tracked_frames = static_cast<int64_t>(tracked.size());
    end.last_frame_id = history.tracked.empty() ? -1 : history.tracked.rbegin()->first;
    end.graph_version = history.graph_version;
    end.done = history.done;
  }
  // Requests that came together are answered with one replay.
  int n = 0;
  auto pace = [&] {
    if (++n % kReplayBurst == 0) std::this_thread::sleep_for(kReplayPause);
  };
  for (const auto& m : keyframes) bus.publish(channel::kKeyframesResent, m), pace();
  for (const auto& m : constraints) bus.publish(channel::kConstraintsResent, m), pace();
  for (const auto& m : tracked) bus.publish(channel::kTrackedFramesResent, m), pace();
  for (const auto& r : requests) {
    end.service = r.service;
    end.request_id = r.request_id;
    bus.publish(channel::kReplayEnd, end);
  }
  spdlog::info("replayed {} keyframes, {} constraints and {} tracked frames for rekon-{}", keyframes.size(),
               constraints.size(), tracked.size(), requests.front().service);
}

}  // namespace

void runTrackerService(ServiceContext& ctx) {
  const TrackerParams params = trackerParamsFromConfig(ctx.config());
  Bus& bus = ctx.bus();
  ServiceState state(params);
  History history;
  std::atomic<int64_t> last_handled{-1};
  std::atomic<int64_t> end_frame{-2};  // -2: no end of stream yet
  std::atomic<int64_t> duplicates{0};
  std::atomic<std::chrono::steady_clock::rep> last_frame_at{std::chrono::steady_clock::now().time_since_epoch().count()};
  LoopClosureWorker loops(params, [&bus, &history](const LoopConstraint& c) { publishLoopConstraint(bus, history, c); });
  PeerWatch peers(bus);

  StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
  peers.onNewInstance([&history](const std::string& service, int instance) {
    if (service != "mapper") return;
    spdlog::warn("rekon-mapper restarted (instance {}): frames sent again get their results again", instance);
    std::lock_guard<std::mutex> lock(history.mutex);
    history.mapper_instance = instance;
  });
  bus.subscribe<rekon_msgs::replay_request_t>(channel::kReplayRequest, [&history](const rekon_msgs::replay_request_t& m) {
    spdlog::info("rekon-{} (pid {}) asks for a replay", m.service, m.pid);
    std::lock_guard<std::mutex> lock(history.mutex);
    history.requests.push_back(m);
  });
  bus.subscribe<rekon_msgs::graph_update_t>(channel::kGraphUpdates, [&loops, &history](const rekon_msgs::graph_update_t& m) {
    {
      std::lock_guard<std::mutex> lock(history.mutex);
      history.graph_version = std::max(history.graph_version, m.version);
    }
    std::unordered_map<int64_t, Pose> poses;
    try {
      for (const auto& [id, pose] : graphPoses(m)) poses.emplace(id, pose);
    } catch (const Error& e) {
      spdlog::error("{}", e.what());
      return;
    }
    loops.updateGraph(m.version, std::move(poses));  // older versions are ignored there
  });

  bus.subscribe<rekon_msgs::end_of_stream_t>(channel::kEndOfStream, [&](const rekon_msgs::end_of_stream_t& m) {
    spdlog::info("end of stream after frame {} ({} frames)", m.last_frame_id, m.frames);
    end_frame.store(m.last_frame_id);
  });
  bus.subscribe<rekon_msgs::frame_t>(channel::kFrames, [&](const rekon_msgs::frame_t& msg) {
    last_frame_at.store(std::chrono::steady_clock::now().time_since_epoch().count());
    bool tracked = false;
    if (msg.frame_id <= last_handled.load()) {
      // Sent again: for a restarted mapper, or because its acknowledgement was lost.
      ++duplicates;
      if (!republishResult(bus, history, msg.frame_id))
        spdlog::warn("frame {} came again but was never tracked (lost on its first way); skipped", msg.frame_id);
    } else {
      std::lock_guard<std::mutex> lock(state.mutex);
      Intrinsics k;
      std::optional<RgbdFrame> frame = state.receiver.receive(msg, &k);
      if (!frame) {
        ++state.undecodable;  // the receiver logged why; acknowledge so the source is not held up
      } else {
        const double t0 = threadCpuMs();
        const auto w0 = std::chrono::steady_clock::now();
        const TrackResult r = state.tracker.track(*frame, k);
        tracked = true;
        state.frame_ms.emplace_back(
            r.frame_id, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - w0).count());
        state.track_cpu_s += 1e-3 * (threadCpuMs() - t0);
        ++state.frames;
        state.lost += r.state == TrackingState::Lost;
        state.keyframes += r.new_keyframe;
        state.constraints += r.odometry.has_value();
        state.odometry.push_back({r.timestamp, r.pose_world});
        if (r.state == TrackingState::Lost)
          spdlog::warn("frame {}: lost ({})", r.frame_id, toString(r.lost_reason));
        publishResult(bus, history, r);
        // After publishResult: a loop constraint never reaches the bus before its keyframe.
        if (r.new_keyframe) loops.submit(state.tracker.currentKeyframe(), r.odometry);
      }
    }
    rekon_msgs::frame_ack_t ack{};
    ack.service = ctx.name();
    ack.frame_id = msg.frame_id;
    bus.publish(channel::kFrameAck, ack);
    // Only a tracked frame moves the mark: a rejected one with a huge id would
    // make every later frame a duplicate and end the stream early.
    if (tracked && msg.frame_id > last_handled.load()) {
      ctx.setLastFrame(msg.frame_id);
      last_handled.store(msg.frame_id);
    }
  });
  ctx.setState("running");
  spdlog::info("tracking levels {}..{}, keyframe criterion {}", params.aligner.coarsest_level,
               params.aligner.finest_level, params.keyframe.criterion);

  bool ended = false;
  auto secondsSinceLastFrame = [&] {
    const auto t = std::chrono::steady_clock::time_point(std::chrono::steady_clock::duration(last_frame_at.load()));
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };
  while (!ctx.stopRequested()) {
    serveReplays(bus, history);
    const int64_t end = end_frame.load();
    if (end != -2 && last_handled.load() >= end) {
      ended = true;
      break;
    }
    if (end != -2 && secondsSinceLastFrame() > kLastFrameGraceS) {
      spdlog::warn("end of stream at frame {} but the last frame tracked is {}: frames {}..{} were lost; finishing",
                   end, last_handled.load(), last_handled.load() + 1, end);
      ended = true;
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ctx.setState("finishing");
  if (ended) {
    // The remaining loop-closure checks, with graph updates still arriving.
    spdlog::info("end of stream: waiting for the loop-closure checks");
    while (!loops.waitUntilDrained(kDrainPollMs) && !ctx.stopRequested()) serveReplays(bus, history);
  }
  if (ended) {
    {
      std::lock_guard<std::mutex> lock(history.mutex);
      history.done = true;
    }
    rekon_msgs::done_t done{};
    done.service = "tracker";
    done.last_frame_id = end_frame.load();
    for (int i = 0; i < kDoneRepeats; ++i) {
      if (i > 0) std::this_thread::sleep_for(kDoneGap);
      bus.publish(channel::kDone, done);
    }
    // Downstream services may still need us: the optimiser asks for a replay
    // to fill what it lost, and a restarted one rebuilds from one; a restarted
    // mapper gets its frames again, whose results go out again from here.
    ctx.setState("lingering");
    while (!ctx.stopRequested() && !peers.finished({"optimiser", "mapper"}, PeerWatch::kSilenceS)) {
      serveReplays(bus, history);
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }
  ctx.stopThreads();  // no handler runs after this
  const LoopClosureStats ls = loops.stats();
  std::vector<double> ms;
  double ms_sum = 0.0;
  for (const auto& f : state.frame_ms) {
    ms.push_back(f.second);
    ms_sum += f.second;
  }

  const double n = static_cast<double>(std::max<int64_t>(state.frames, 1));
  ctx.stats()
      .set("frames", static_cast<long long>(state.frames))
      .set("lost_frames", static_cast<long long>(state.lost))
      .set("keyframes", static_cast<long long>(state.keyframes))
      .set("odometry_constraints", static_cast<long long>(state.constraints))
      .set("undecodable_frames", static_cast<long long>(state.undecodable))
      .set("frames_sent_again", static_cast<long long>(duplicates.load()))
      .set("track_cpu_ms_per_frame", 1e3 * state.track_cpu_s / n)
      .set("ms_per_frame_mean", ms_sum / n)
      .set("ms_per_frame_p95", percentile(ms, 0.95))
      .set("loop_candidates", static_cast<long long>(ls.candidates))
      .set("loop_closures_accepted", static_cast<long long>(ls.accepted))
      .set("loop_closures_rejected", static_cast<long long>(ls.rejected))
      .set("loop_candidates_skipped", static_cast<long long>(ls.candidates_skipped))
      .set("loop_checks_dropped", static_cast<long long>(ls.checks_dropped))
      .set("loop_check_ms_per_keyframe",
           ls.check_ms / static_cast<double>(std::max<int64_t>(ls.keyframes_checked, 1)));
  if (!ctx.outDir().empty()) {
    const std::string path = (std::filesystem::path(ctx.outDir()) / "odometry.txt").string();
    writeTumTrajectory(state.odometry, path);
    spdlog::info("wrote {} odometry poses to {}", state.odometry.size(), path);
    writeTiming(state.frame_ms, (std::filesystem::path(ctx.outDir()) / "tracker_timing.csv").string());
  }
  spdlog::info("loop closures: {} candidates, {} accepted, {} rejected, {} checks dropped", ls.candidates,
               ls.accepted, ls.rejected, ls.checks_dropped);
  spdlog::info("tracked {} frames ({} lost), {} keyframes, {:.2f} ms CPU per frame", state.frames, state.lost,
               state.keyframes, 1e3 * state.track_cpu_s / n);
}

}  // namespace rekon::tracker
