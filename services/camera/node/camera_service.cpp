#include "camera_service.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <optional>
#include <thread>

#include "rekon/camera/device_clock.hpp"
#include "rekon/camera/recorder.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_source.hpp"

namespace rekon::camera {
namespace {

using Clock = std::chrono::steady_clock;

// How a capture went: "" for the end of a recording or a stop, else the
// one line that says what happened to the device and what to do; the frame
// ids (continued by a restarted camera), and the outages it came back from.
struct CaptureEnd {
  std::string lost;
  int64_t first_id = 0, frames = 0;
  double first_timestamp = 0, last_timestamp = 0;
  int64_t outages = 0, frames_missed = 0;  // frames the device would have sent while it was away (at its rate)
  double outage_s = 0;
};

// The device again after it was lost at `since`: reopened with a doubling
// wait (camera.reconnect_wait_s, at most 8 times that) until
// camera.reconnect_timeout_s after `since`; nullptr when it stays away, the
// run stops, or another camera (other intrinsics) answers.
std::unique_ptr<CameraSource> reopen(ServiceContext& ctx, const CameraParams& params, const Intrinsics& k,
                                     Clock::time_point since) {
  double wait_s = params.reconnect_wait_s;
  for (int attempt = 1; !ctx.stopRequested(); ++attempt) {
    const double waited = std::chrono::duration<double>(Clock::now() - since).count();
    if (waited + wait_s > params.reconnect_timeout_s) return nullptr;
    std::this_thread::sleep_for(std::chrono::duration<double>(wait_s));
    try {
      std::unique_ptr<CameraSource> source = openCamera(params.device, params.source);
      if (!sameCamera(source->intrinsics(), k)) {
        spdlog::error("camera {} came back as another camera ({} instead of {}); not using it", params.device,
                      describeCamera(source->intrinsics()), describeCamera(k));
        return nullptr;
      }
      return source;
    } catch (const Error& e) {
      spdlog::info("camera {}: attempt {} to reopen it failed ({})", params.device, attempt, e.what());
    }
    wait_s = std::min(2 * wait_s, 8 * params.reconnect_wait_s);
  }
  return nullptr;
}

// In stats.json, and live (STATS: the viewer's status shows them).
void noteOutages(ServiceContext& ctx, const CaptureEnd& end) {
  ctx.setLive("outages", static_cast<double>(end.outages));
  ctx.setLive("frames_missed_in_outages", static_cast<double>(end.frames_missed));
  ctx.stats()
      .set("outages", static_cast<long long>(end.outages))
      .set("frames_missed_in_outages", static_cast<long long>(end.frames_missed))
      .set("outage_seconds", end.outage_s);
}

// Takes frames from the device until it ends, is lost for longer than
// camera.reconnect_timeout_s, max_frames are captured, or the run stops;
// every frame goes to the recorder and the outlet, its id after the last.
CaptureEnd capture(ServiceContext& ctx, const CameraParams& params, std::unique_ptr<CameraSource>& source,
                   LiveOutlet& outlet, Recorder* recorder, int64_t first_id) {
  CaptureEnd end;
  end.first_id = first_id;
  const Intrinsics k = source->intrinsics();
  auto last_report = Clock::now();
  const auto start = last_report;
  int64_t replaced_before = 0;
  // Set while the device is away: until a frame comes again (one that opens
  // but sends nothing is not back).
  std::optional<std::pair<Clock::time_point, double>> lost_at;  // steady and host clock
  while (!ctx.stopRequested() && (params.max_frames <= 0 || end.frames < params.max_frames)) {
    Capture c = source->next(0.5);
    if (c.status == Capture::Status::kTimeout) continue;
    if (c.status == Capture::Status::kEnded) {
      spdlog::info("the recording has ended after {} frames", end.frames);
      break;
    }
    if (c.status == Capture::Status::kLost) {
      outlet.skippedLate(source->framesReplaced() - replaced_before);
      replaced_before = 0;
      source.reset();  // the driver lets go of the device before it is opened again
      if (params.reconnect_timeout_s > 0) {
        if (!lost_at) {
          lost_at.emplace(Clock::now(), hostWallSeconds());
          spdlog::warn("{}; reopening it for up to {:.0f} s (camera.reconnect_timeout_s)", c.reason, params.reconnect_timeout_s);
        }
        source = reopen(ctx, params, k, lost_at->first);
      }
      if (!source) {
        spdlog::error("{}", c.reason);
        end.lost = c.reason;
        break;
      }
      continue;
    }
    if (lost_at) {
      const double away_s = hostWallSeconds() - lost_at->second;
      const auto missed = static_cast<int64_t>(away_s * params.source.fps);
      ++end.outages, end.frames_missed += missed, end.outage_s += away_s;
      noteOutages(ctx, end);
      spdlog::warn("camera {} is back after {:.1f} s (about {} frames missed); frame ids go on from {}", params.device,
                   away_s, missed, end.first_id + end.frames);
      lost_at.reset();
    }
    // Frames the driver replaced before this loop took them: the loop was
    // late for them (a starved process), as the player skips frames whose
    // time has passed.
    const int64_t replaced = source->framesReplaced();
    outlet.skippedLate(replaced - replaced_before);
    replaced_before = replaced;
    c.frame.id = end.first_id + end.frames++;
    if (end.frames == 1) end.first_timestamp = c.frame.timestamp;
    end.last_timestamp = c.frame.timestamp;
    if (recorder) recorder->push(c.frame);
    outlet.offer(std::move(c.frame), k, hostWallSeconds() - c.host_time);
    if (std::chrono::duration<double>(Clock::now() - last_report).count() > 2.0) {
      last_report = Clock::now();
      const auto n = outlet.counts();
      spdlog::info("captured {} frames ({:.1f} frames/s), sent {}, dropped {}, skipped late {}", n.offered,
                   static_cast<double>(n.offered) / std::chrono::duration<double>(last_report - start).count(), n.sent,
                   n.dropped, n.skipped_late);
    }
  }
  if (source) outlet.skippedLate(source->framesReplaced() - replaced_before);
  return end;
}

void writeStats(ServiceContext& ctx, const CameraParams& params, const CaptureEnd& end, const LiveOutlet& outlet,
                const Recorder* recorder, TransportMode mode) {
  JsonObject& stats = ctx.stats();
  // frames_skipped_late: those the driver replaced before the capture loop took them.
  outlet.writeStats(stats);
  const LiveOutlet::Counts c = outlet.counts();
  const double span = end.frames > 1 ? (end.last_timestamp - end.first_timestamp) * static_cast<double>(end.frames) /
                                           static_cast<double>(end.frames - 1)
                                     : 0.0;
  stats.set("device", params.device)
      .set("frames", static_cast<long long>(c.sent))
      .set("sequence_seconds", span)
      .set("transport", mode == TransportMode::kShm ? "shm" : "lcm")
      .set("end", end.lost.empty() ? "end of stream" : "device lost: " + end.lost);
  noteOutages(ctx, end);
  if (params.restarted) stats.set("restarted_at_frame", static_cast<long long>(end.first_id));
  if (recorder) {
    stats.set("record_folder", params.record)
        .set("frames_recorded", static_cast<long long>(recorder->written()))
        .set("record_dropped", static_cast<long long>(recorder->dropped()))
        .set("record_failed", static_cast<long long>(recorder->failed()));
  }
}

}  // namespace

CameraParams CameraParams::fromConfig(const Config& config) {
  CameraParams p;
  p.device = config.getString("camera.device");
  if (p.device.empty()) {
    throw Error("no camera given: set camera.device (rekon-camera --device openni2[:URI] or freenect[:INDEX]); "
                "rekon cameras lists what is connected");
  }
  const std::string calibration = config.getString("camera.calibration");
  if (!calibration.empty()) p.source.calibration_file = calibration;
  p.source.width = config.getInt("camera.width");
  p.source.height = config.getInt("camera.height");
  p.source.fps = config.getInt("camera.fps");
  const std::string clock = config.getString("camera.clock");
  if (clock != "host" && clock != "recording")
    throw Error("config key camera.clock must be 'host' (this computer's clock: live scans) or 'recording' (a "
                "recording's own times), not '" + clock + "'");
  p.source.recording_clock = clock == "recording";
  p.record = config.getString("camera.record");
  p.record_queue = config.getInt("camera.record_queue");
  p.wait_for = config.getStringList("camera.wait_for");
  p.wait_timeout_s = config.getDouble("camera.wait_timeout_s");
  p.max_frames = config.getInt("camera.max_frames");
  p.reconnect_timeout_s = config.getDouble("camera.reconnect_timeout_s");
  p.reconnect_wait_s = config.getDouble("camera.reconnect_wait_s");
  if (!(p.reconnect_wait_s > 0)) throw Error("camera.reconnect_wait_s must be a positive number of seconds");
  if (p.reconnect_timeout_s < 0) throw Error("camera.reconnect_timeout_s must be 0 (never reopen) or more seconds");
  p.restarted = config.getBool("camera.restarted");
  p.transport_mode = config.getString("transport.mode");
  p.segment = config.getString("transport.segment");
  p.slots = config.getInt("transport.slots");
  p.max_width = config.getInt("transport.max_width");
  p.max_height = config.getInt("transport.max_height");
  p.in_flight = config.getInt("transport.live_in_flight");
  if (p.transport_mode != "auto") parseTransportMode(p.transport_mode);
  if (p.in_flight < 1) throw Error("transport.live_in_flight must be 1 or more");
  if (p.record_queue < 1) throw Error("camera.record_queue must be 1 or more (frames)");
  return p;
}

void runCamera(ServiceContext& ctx, const CameraParams& params) {
  ConsumerWatch watch(ctx.bus());
  PeerWatch peers(ctx.bus(), ctx.lifecycle());
  StopThreadsOnExit stop_threads(ctx);  // after `watch` and `peers`: their handlers run on the bus thread
  // The device opens once its consumers listen: a camera cannot be paused,
  // so frames captured before would only be dropped.
  waitForConsumers(ctx, watch, params.wait_for, params.wait_timeout_s, "camera.wait_for");
  std::unique_ptr<CameraSource> source = openCamera(params.device, params.source);
  const Intrinsics k = source->intrinsics();
  spdlog::info("camera {}: {}", params.device, source->describe());
  if (!ctx.outDir().empty()) saveIntrinsics(k, ctx.outDir() + "/camera.yaml");  // the calibration in effect
  std::optional<Recorder> recorder;
  if (!params.record.empty()) recorder.emplace(params.record, k, params.record_queue);

  const TransportMode mode = chooseTransport(params.transport_mode, params.wait_for, watch);
  FrameSender sender(ctx.bus(), mode, params.segment, FrameRingLayout{params.slots, params.max_width, params.max_height});
  LiveOutlet outlet(ctx, sender, watch, params.wait_for, params.in_flight);
  ctx.setState("capturing");
  // A restarted camera (the launcher restarts a killed one) numbers its
  // frames after the newest its consumers have: an id from 0 again would be
  // taken for a frame they already had.
  int64_t first_id = 0;
  if (params.restarted) {
    for (const auto& s : params.wait_for) first_id = std::max(first_id, watch.lastFrame(s) + 1);
    spdlog::warn("restarted: the consumers have the frames up to {}; frame ids go on from {}", first_id - 1, first_id);
  }
  const CaptureEnd end = capture(ctx, params, source, outlet, recorder ? &*recorder : nullptr, first_id);
  outlet.finish(params.wait_timeout_s);
  if (recorder) recorder->close();
  writeStats(ctx, params, end, outlet, recorder ? &*recorder : nullptr, mode);
  const LiveOutlet::Counts c = outlet.counts();
  spdlog::info("captured {} frames: {} sent, {} dropped (the consumers were not ready), {} skipped late (replaced in "
               "the driver before they were taken){}",
               c.offered, c.sent, c.dropped, c.skipped_late,
               recorder ? fmt::format(", {} recorded, {} not recorded (the disk did not keep up)", recorder->written(),
                                      recorder->dropped() + recorder->failed())
                        : "");
  rekon_msgs::end_of_stream_t eos{};
  eos.last_frame_id = c.newest_sent;
  eos.frames = c.sent;
  eos.duration_s = end.last_timestamp - end.first_timestamp;
  announceEndOfStream(ctx.bus(), eos);
  lingerAfterLiveEnd(ctx, watch, peers, params.wait_for, eos);
}

}  // namespace rekon::camera
