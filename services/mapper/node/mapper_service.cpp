#include "mapper_service.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <thread>
#include <variant>

#include "rekon/common/error.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/mapper/mapper.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/resume_point_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::mapper {
namespace {

struct Tracked {
  int64_t keyframe_id;
  Pose pose_in_keyframe;
  bool lost;
};
struct FrameWork {
  RgbdFrame frame;
  Intrinsics k;
  Tracked tracked;
};
struct KeyframeWork {
  int64_t id;
  Pose world;
};
struct GraphWork {
  int64_t version;
  std::vector<std::pair<int64_t, Pose>> poses;
};
// The stream is over but the optimiser is not done yet: the worker would be
// idle, so it closes the last KF keyframe and writes mesh_uncorrected.ply now
// rather than after the final pass.
struct BaselineWork {};
using Work = std::variant<FrameWork, KeyframeWork, GraphWork, BaselineWork>;

// What the bus thread and the worker share, behind one mutex.
struct Shared {
  std::mutex mutex;
  std::condition_variable work_ready, idle;
  std::deque<Work> queue;
  std::map<int64_t, std::pair<RgbdFrame, Intrinsics>> images;  // copied, waiting for their tracked frame
  std::map<int64_t, Tracked> tracked;                         // waiting for their images
  std::deque<int64_t> deferred_acks;
  size_t frames_in_queue = 0;  // joined frames queued or being fused
  bool busy = false, stop_worker = false;
  int64_t end_frame = -2;  // -2: no end of stream yet
  int64_t last_resolved = -1;  // newest frame joined or given up on
  bool optimiser_done = false, tracker_done = false;
  int64_t dropped_frames = 0, dropped_updates = 0, coalesced_updates = 0;
  // Copies of a frame already here (the player sends its newest frame again
  // while acknowledgements stall): neither stored nor counted as dropped.
  int64_t frames_received_again = 0;
  bool baseline_queued = false;
  std::string worker_error;
  MapperCounters progress;  // the worker's copy after each piece of work, for the progress log

  // Frames held in memory: images waiting for their tracked frame, and joined
  // frames not yet fused. Counted from the containers, so no message order can
  // make it drift (a counter of its own leaked one per re-sent frame and
  // deferred every acknowledgement for good: the stall near frame 8 700).
  size_t queuedFrames() const { return images.size() + frames_in_queue; }
  // A frame whose images came before, or that was joined or given up on.
  bool seen(int64_t id) const { return id <= last_resolved || images.count(id) > 0; }
  bool ackDeferred(int64_t id) const { return std::find(deferred_acks.begin(), deferred_acks.end(), id) != deferred_acks.end(); }
};

bool contains(const std::vector<std::string>& list, const std::string& s) {
  return std::find(list.begin(), list.end(), s) != list.end();
}

// One row of mapper_timing.csv (tools/report/README.md): the wall time of a
// frame, split into keyframe fusion and the integration of a KF keyframe it closed.
struct FrameTiming {
  int64_t frame_id;
  double ms, fuse_ms, integrate_ms;
};
// One row of mapper_reintegration.csv.
struct RoundRecord {
  double time_s;
  int64_t graph_version;
  ReintegrationRound round;
  bool final_pass;
};

void writeFrameTiming(const std::vector<FrameTiming>& rows, const std::string& path) {
  std::ofstream out(path);
  out << "frame_id,ms,fuse_ms,integrate_ms\n";
  for (const FrameTiming& r : rows) out << r.frame_id << ',' << r.ms << ',' << r.fuse_ms << ',' << r.integrate_ms << '\n';
  if (!out) throw Error("cannot write " + path + "; check that the output folder is writable");
}

void writeRounds(const std::vector<RoundRecord>& rows, const std::string& path) {
  std::ofstream out(path);
  out << "time_s,graph_version,keyframes_reintegrated,ms,blocks_streamed,final_pass\n";
  for (const RoundRecord& r : rows)
    out << r.time_s << ',' << r.graph_version << ',' << r.round.keyframes << ',' << r.round.ms << ','
        << r.round.blocks_streamed << ',' << (r.final_pass ? 1 : 0) << '\n';
  if (!out) throw Error("cannot write " + path + "; check that the output folder is writable");
}

}  // namespace

void runMapperService(ServiceContext& ctx) {
  const MapperParams params = MapperParams::fromConfig(ctx.config());
  const size_t max_queued = static_cast<size_t>(std::max(1, ctx.config().getInt("mapper.max_queued_frames")));
  const bool write_uncorrected = ctx.config().getBool("mapper.write_uncorrected_mesh");
  const auto progress_every = std::chrono::duration<double>(ctx.config().getDouble("mapper.progress_interval_s"));
  const bool wait_for_optimiser =
      ctx.config().getBool("mapper.wait_for_optimiser") && contains(ctx.config().getStringList("run.services"), "optimiser");
  Bus& bus = ctx.bus();
  Mapper mapper(params);
  Shared s;
  GraphUpdateFilter filter;  // each update carries every pose: only the newest matters
  FrameReceiver receiver;
  // Written by the worker only (read after it joined).
  std::vector<FrameTiming> frame_timing;
  std::vector<RoundRecord> rounds;
  std::optional<std::chrono::steady_clock::time_point> first_frame_time;
  int64_t last_graph_version = 0;
  auto secondsSinceFirstFrame = [&] {
    if (!first_frame_time) return 0.0;
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - *first_frame_time).count();
  };

  auto ack = [&](int64_t frame_id) {
    rekon_msgs::frame_ack_t a{};
    a.service = ctx.name();
    a.frame_id = frame_id;
    bus.publish(channel::kFrameAck, a);
  };
  // mesh_uncorrected.ply: every KF keyframe at the pose of its first
  // integration. With reintegration none mesh.ply already is that baseline.
  const bool baseline_wanted = write_uncorrected && params.mode != ReintegrationMode::kNone && !ctx.outDir().empty();
  bool baseline_written = false;  // by the worker (read after it joined)
  auto writeBaseline = [&] {
    const auto t0 = std::chrono::steady_clock::now();
    const std::string path = (std::filesystem::path(ctx.outDir()) / "mesh_uncorrected.ply").string();
    const Mesh uncorrected = mapper.extractUncorrectedMesh();
    writePly(uncorrected, path);
    spdlog::info("wrote {} ({} vertices, {:.1f} s: every KF keyframe at its first pose)", path, uncorrected.vertices.size(),
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    baseline_written = true;
  };
  // Under the lock: moves a frame whose images and pose both arrived into the queue.
  auto join = [&](int64_t id) {
    auto img = s.images.find(id);
    auto tr = s.tracked.find(id);
    if (img == s.images.end() || tr == s.tracked.end()) return;
    s.queue.push_back(FrameWork{std::move(img->second.first), img->second.second, tr->second});
    ++s.frames_in_queue;
    s.images.erase(img);
    s.tracked.erase(tr);
    s.last_resolved = std::max(s.last_resolved, id);
    s.work_ready.notify_one();
  };

  StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
  bus.subscribe<rekon_msgs::frame_t>(channel::kFrames, [&](const rekon_msgs::frame_t& msg) {
    std::optional<bool> again_ack;  // set for a frame sent again: whether to acknowledge it now
    {
      std::lock_guard<std::mutex> lock(s.mutex);
      if (s.seen(msg.frame_id)) {
        // Sent again: the first copy is (or was) in the work. Acknowledged
        // again unless its acknowledgement is still held back.
        ++s.frames_received_again;
        again_ack = !s.ackDeferred(msg.frame_id);
      }
    }
    if (again_ack) {
      if (*again_ack) ack(msg.frame_id);
      return;
    }
    Intrinsics k;
    std::optional<RgbdFrame> frame = receiver.receive(msg, &k);  // a copy out of the ring: safe to acknowledge
    bool ack_now = true;
    {
      std::lock_guard<std::mutex> lock(s.mutex);
      if (frame) {
        // A tracked frame older than this image whose image never came (dropped by the transport) never will.
        while (!s.tracked.empty() && s.tracked.begin()->first < msg.frame_id) {
          s.last_resolved = std::max(s.last_resolved, s.tracked.begin()->first);
          s.tracked.erase(s.tracked.begin());
          ++s.dropped_frames;
        }
        s.images[msg.frame_id] = {std::move(*frame), k};
        join(msg.frame_id);
        if (s.queuedFrames() > max_queued) {
          s.deferred_acks.push_back(msg.frame_id);
          ack_now = false;
        }
      } else {
        ++s.dropped_frames;
      }
    }
    if (ack_now) ack(msg.frame_id);
    ctx.setLastFrame(msg.frame_id);
  });
  bus.subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFrames, [&](const rekon_msgs::tracked_frame_t& msg) {
    const auto pose = fromMsg(msg.pose_in_keyframe);
    std::lock_guard<std::mutex> lock(s.mutex);
    if (!pose) {
      spdlog::error("tracked frame {}: invalid pose_in_keyframe; dropped", msg.frame_id);
      s.last_resolved = std::max(s.last_resolved, msg.frame_id);
      return;
    }
    // Tracked frames come in order: older images without one will never get it.
    while (!s.images.empty() && s.images.begin()->first < msg.frame_id) {
      spdlog::warn("frame {}: no tracked frame came for it; dropped", s.images.begin()->first);
      s.last_resolved = std::max(s.last_resolved, s.images.begin()->first);
      s.images.erase(s.images.begin());
      ++s.dropped_frames;
    }
    s.tracked[msg.frame_id] = {msg.keyframe_id, *pose, msg.state == rekon_msgs::tracked_frame_t::STATE_LOST};
    join(msg.frame_id);
  });
  bus.subscribe<rekon_msgs::keyframe_t>(channel::kKeyframes, [&](const rekon_msgs::keyframe_t& msg) {
    const auto pose = fromMsg(msg.pose_world);
    if (!pose) {
      spdlog::error("keyframe {}: invalid pose_world; dropped", msg.keyframe_id);
      return;
    }
    std::lock_guard<std::mutex> lock(s.mutex);
    s.queue.push_back(KeyframeWork{msg.keyframe_id, *pose});
    s.work_ready.notify_one();
  });
  bus.subscribe<rekon_msgs::graph_update_t>(channel::kGraphUpdates, [&](const rekon_msgs::graph_update_t& msg) {
    if (!filter.accept(msg.version)) return;
    GraphWork g{msg.version, {}};
    try {
      g.poses = graphPoses(msg);
    } catch (const Error& e) {
      spdlog::error("{}", e.what());
      std::lock_guard<std::mutex> lock(s.mutex);
      ++s.dropped_updates;
      return;
    }
    std::lock_guard<std::mutex> lock(s.mutex);
    // Every update carries all poses: a newer one replaces one still waiting.
    for (Work& w : s.queue) {
      if (std::holds_alternative<GraphWork>(w)) {
        w = std::move(g);
        ++s.coalesced_updates;
        return;
      }
    }
    s.queue.push_back(std::move(g));
    s.work_ready.notify_one();
  });
  bus.subscribe<rekon_msgs::end_of_stream_t>(channel::kEndOfStream, [&](const rekon_msgs::end_of_stream_t& m) {
    spdlog::info("end of stream after frame {} ({} frames)", m.last_frame_id, m.frames);
    std::lock_guard<std::mutex> lock(s.mutex);
    s.end_frame = m.last_frame_id;
  });
  bus.subscribe<rekon_msgs::done_t>(channel::kDone, [&](const rekon_msgs::done_t& m) {
    std::lock_guard<std::mutex> lock(s.mutex);
    if (m.service == "optimiser" && !s.optimiser_done) {
      spdlog::info("the optimiser is done");
      s.optimiser_done = true;
    }
    if (m.service == "tracker") s.tracker_done = true;
  });

  std::thread worker([&] {
    std::unique_lock<std::mutex> lock(s.mutex);
    while (true) {
      s.work_ready.wait(lock, [&] { return s.stop_worker || !s.queue.empty(); });
      if (s.queue.empty()) break;
      Work w = std::move(s.queue.front());
      s.queue.pop_front();
      s.busy = true;
      lock.unlock();
      try {
        if (auto* f = std::get_if<FrameWork>(&w)) {
          const auto t0 = std::chrono::steady_clock::now();
          if (!first_frame_time) first_frame_time = t0;
          const MapperCounters before = mapper.counters();
          mapper.addFrame(f->frame, f->k, f->tracked.keyframe_id, f->tracked.pose_in_keyframe, f->tracked.lost);
          const MapperCounters& after = mapper.counters();
          frame_timing.push_back({f->frame.id,
                                  std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(),
                                  after.fuse_ms_total - before.fuse_ms_total,
                                  after.first_integration_ms_total - before.first_integration_ms_total});
        } else if (auto* kf = std::get_if<KeyframeWork>(&w)) {
          mapper.setKeyframeEstimate(kf->id, kf->world);
        } else if (std::holds_alternative<BaselineWork>(w)) {
          mapper.flush();  // no frame comes after the end of the stream: the last KF keyframe is complete
          writeBaseline();
        } else {
          const GraphWork& g = std::get<GraphWork>(w);
          const ReintegrationRound round = mapper.applyGraphUpdate(g.poses);
          last_graph_version = g.version;
          rounds.push_back({secondsSinceFirstFrame(), g.version, round, false});
        }
      } catch (const std::exception& e) {  // rekon::Error, or OpenCV's for a broken image
        lock.lock();
        s.worker_error = e.what();
        s.busy = false;
        s.idle.notify_all();
        ctx.requestStop();
        return;
      }
      lock.lock();
      s.busy = false;
      s.progress = mapper.counters();
      if (std::holds_alternative<FrameWork>(w)) --s.frames_in_queue;
      std::vector<int64_t> release;
      while (!s.deferred_acks.empty() && s.queuedFrames() <= max_queued) {
        release.push_back(s.deferred_acks.front());
        s.deferred_acks.pop_front();
      }
      if (s.queue.empty()) s.idle.notify_all();
      if (!release.empty()) {
        lock.unlock();
        for (int64_t id : release) ack(id);
        lock.lock();
      }
    }
  });

  // Where the frame source resumes for this instance: after the frames of
  // the keyframes it restored from its store (a restart), or from the first.
  rekon_msgs::resume_point_t resume_point{};
  resume_point.service = ctx.name();
  resume_point.pid = static_cast<int32_t>(getpid());
  resume_point.first_missing_frame = mapper.firstMissingFrame();
  bus.publish(channel::kResumePoint, resume_point);
  auto last_resume_point = std::chrono::steady_clock::now();
  if (resume_point.first_missing_frame >= 0)
    spdlog::info("mapper: resuming after frame {} (the newest in the keyframe store)", resume_point.first_missing_frame - 1);
  ctx.setState("running");
  spdlog::info("mapper: KF strategy {} (kappa {}), re-integration {} (m = {}), streaming radius {} m, {}",
               fusion::toString(params.fusion.strategy), params.fusion.kappa, toString(params.mode), params.m,
               params.volume.streaming_radius, wait_for_optimiser ? "final pass after the optimiser's done" : "final pass after the last frame");
  auto last_progress = std::chrono::steady_clock::now();
  while (!ctx.stopRequested()) {
    {
      std::lock_guard<std::mutex> lock(s.mutex);
      const bool frames_done = s.end_frame != -2 && (s.tracker_done || s.last_resolved >= s.end_frame);
      if (s.end_frame != -2 && (wait_for_optimiser ? s.optimiser_done : frames_done)) break;
      if (frames_done && baseline_wanted && !s.baseline_queued) {
        s.baseline_queued = true;
        s.queue.push_back(BaselineWork{});  // after every frame's work
        s.work_ready.notify_one();
      }
    }
    if (std::chrono::steady_clock::now() - last_resume_point > std::chrono::seconds(1)) {
      last_resume_point = std::chrono::steady_clock::now();
      bus.publish(channel::kResumePoint, resume_point);  // again: a frame source that missed it still finds it
    }
    if (std::chrono::steady_clock::now() - last_progress > progress_every) {
      last_progress = std::chrono::steady_clock::now();
      std::lock_guard<std::mutex> lock(s.mutex);  // the worker's copy: the mapper's own counters are its alone
      spdlog::info("mapper: {} frames fused into {} KF keyframes, {} re-integrations, {} frames queued", s.progress.frames,
                   s.progress.kf_keyframes, s.progress.reintegrations, s.queuedFrames());
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  const bool clean = !ctx.stopRequested();
  ctx.setState("finishing");
  {
    std::unique_lock<std::mutex> lock(s.mutex);
    s.idle.wait(lock, [&] { return (s.queue.empty() && !s.busy) || !s.worker_error.empty(); });
    s.stop_worker = true;
    s.work_ready.notify_all();
  }
  worker.join();
  ctx.stopThreads();  // no handler runs after this
  if (!s.worker_error.empty()) throw Error(s.worker_error);
  if (!s.images.empty()) {
    spdlog::warn("{} frames never got a tracked frame; dropped", s.images.size());
    s.dropped_frames += static_cast<int64_t>(s.images.size());
  }

  if (clean) {
    for (const ReintegrationRound& r : mapper.finish()) rounds.push_back({secondsSinceFirstFrame(), last_graph_version, r, true});
  } else {
    mapper.flush();
    spdlog::warn("mapper stopped before the end: no final pass; the keyframe store is kept (mapper.resume=true continues from it)");
  }
  if (!ctx.outDir().empty()) {
    const std::string path = (std::filesystem::path(ctx.outDir()) / "mesh.ply").string();
    const Mesh mesh = mapper.extractMesh();
    writePly(mesh, path);
    spdlog::info("wrote {} ({} vertices)", path, mesh.vertices.size());
    const std::filesystem::path out(ctx.outDir());
    writeFrameTiming(frame_timing, (out / "mapper_timing.csv").string());
    writeRounds(rounds, (out / "mapper_reintegration.csv").string());
    if (baseline_wanted && !baseline_written) writeBaseline();
  }
  if (clean) {
    rekon_msgs::done_t done{};
    done.service = ctx.name();
    done.last_frame_id = s.end_frame;
    for (int i = 0; i < 3; ++i) {  // UDP multicast may drop one
      bus.publish(channel::kDone, done);
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }
  const MapperCounters& c = mapper.counters();
  const volume::VolumeStats vs = mapper.volume().stats();
  const MemoryUse mem = mapper.memoryUse();
  const double n_frames = static_cast<double>(std::max<int64_t>(1, c.frames + c.skipped_frames));
  ctx.stats()
      .set("frames_fused", static_cast<long long>(c.frames))
      .set("frames_skipped", static_cast<long long>(c.skipped_frames))
      .set("frames_dropped", static_cast<long long>(s.dropped_frames))
      .set("frames_received_again", static_cast<long long>(s.frames_received_again))
      .set("kf_keyframes", static_cast<long long>(c.kf_keyframes))
      .set("integrations", static_cast<long long>(c.integrations))
      .set("deintegrations", static_cast<long long>(c.deintegrations))
      .set("reintegrations", static_cast<long long>(c.reintegrations))
      .set("final_pass_reintegrations", static_cast<long long>(c.final_pass_reintegrations))
      .set("graph_updates", static_cast<long long>(c.graph_updates))
      .set("graph_updates_coalesced", static_cast<long long>(s.coalesced_updates))
      .set("restored_keyframes", static_cast<long long>(c.restored_keyframes))
      .set("integrate_ms_mean", c.integrate_ms_total / static_cast<double>(std::max<int64_t>(1, c.integrations + c.reintegrations)))
      .set("voxel_blocks", static_cast<long long>(vs.blocks))
      .set("bytes_per_voxel", vs.bytes_per_voxel)
      .set("active_blocks_peak", static_cast<long long>(vs.peak_active_blocks))
      .set("streamed_out", static_cast<long long>(vs.streamed_out))
      .set("streamed_in", static_cast<long long>(vs.streamed_in))
      .set("fuse_ms_per_frame", c.fuse_ms_total / n_frames)
      .set("integration_ms_per_frame", c.first_integration_ms_total / n_frames)
      .set("reintegration_ms_per_frame", c.reintegration_ms_total / n_frames)
      .set("final_pass_ms", c.final_pass_ms_total)
      .set("reintegration_blocks_streamed", static_cast<long long>(c.reintegration_blocks_streamed))
      .set("input_frame_bytes", static_cast<long long>(mem.input_frame_bytes))
      .set("keyframe_bytes", static_cast<long long>(mem.keyframe_bytes))
      .set("keyframe_over_input_bytes",
           static_cast<double>(mem.keyframe_bytes) / static_cast<double>(std::max<int64_t>(1, mem.input_frame_bytes)))
      .set("voxel_bytes", static_cast<long long>(mem.voxel_bytes))
      .set("active_voxel_bytes_peak", static_cast<long long>(mem.active_voxel_bytes_peak))
      .set("reintegration", toString(params.mode))
      .set("m", params.m)
      .set("kappa", params.fusion.kappa);
  if (mem.keyframe_store_bytes >= 0) ctx.stats().set("keyframe_store_bytes", static_cast<long long>(mem.keyframe_store_bytes));
  spdlog::info("mapper: {} frames into {} KF keyframes; {} re-integrations ({} in the final pass); {} blocks",
               c.frames, c.kf_keyframes, c.reintegrations, c.final_pass_reintegrations, vs.blocks);
  if (clean) mapper.removeStore();
}

}  // namespace rekon::mapper
