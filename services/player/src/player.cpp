#include "rekon/player/player.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/resume_point_t.hpp"

namespace rekon {
namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// Without any acknowledgement for this long, the newest frame is sent again:
// the frame or its acknowledgements were lost (lcm.drop_fraction, a full
// socket buffer), and an acknowledgement of the newest covers every older one.
constexpr double kResendAfterS = 1.0;
// A restarted consumer that keeps state sends its resume point as it starts
// and once a second after; one not heard within this long keeps none.
constexpr double kResumePointWaitS = 3.0;

// What the player hears from its consumers: who is alive where (and under
// which pid: a new one is a restart), and how far each has acknowledged.
class ConsumerWatch {
 public:
  enum class Wait { kAcked, kRestarted, kStalled, kStopped };

  explicit ConsumerWatch(Bus& bus) {
    bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [this](const rekon_msgs::heartbeat_t& hb) {
      // A service counts once it has subscribed to its inputs ("running");
      // frames sent while it is still "starting" would be lost to it.
      if (hb.state == "starting") return;
      std::lock_guard<std::mutex> lock(mutex_);
      hosts_[hb.service] = hb.host;
      auto& pid = pids_[hb.service];
      if (pid != 0 && pid != hb.pid) restarted_.insert(hb.service);
      pid = hb.pid;
      changed_.notify_all();
    });
    bus.subscribe<rekon_msgs::resume_point_t>(channel::kResumePoint, [this](const rekon_msgs::resume_point_t& r) {
      std::lock_guard<std::mutex> lock(mutex_);
      resume_points_[{r.service, r.pid}] = r.first_missing_frame;
      changed_.notify_all();
    });
    bus.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [this](const rekon_msgs::frame_ack_t& ack) {
      std::lock_guard<std::mutex> lock(mutex_);
      auto& acked = acked_[ack.service];
      if (ack.frame_id > acked) {
        acked = ack.frame_id;
        last_ack_ = Clock::now();
      }
      changed_.notify_all();
    });
  }

  // Waits until every service in `names` has sent a heartbeat; returns the
  // names still missing after `timeout_s` (empty on success).
  std::vector<std::string> waitForHeartbeats(const std::vector<std::string>& names, double timeout_s,
                                             const ServiceContext& ctx) {
    std::unique_lock<std::mutex> lock(mutex_);
    const auto deadline = Clock::now() + std::chrono::duration<double>(timeout_s);
    auto missing = [&] {
      std::vector<std::string> m;
      for (const auto& n : names) {
        if (!hosts_.count(n)) m.push_back(n);
      }
      return m;
    };
    while (!missing().empty() && Clock::now() < deadline && !ctx.stopRequested()) {
      changed_.wait_for(lock, std::chrono::milliseconds(100));
    }
    return missing();
  }

  bool allOnHost(const std::vector<std::string>& names, const std::string& host) {
    std::lock_guard<std::mutex> lock(mutex_);
    return std::all_of(names.begin(), names.end(), [&](const std::string& n) { return hosts_[n] == host; });
  }

  // Waits until every service in `names` acknowledged frame `frame_id`, a
  // consumer restarted, or no acknowledgement came for `stall_s`.
  Wait waitForAck(const std::vector<std::string>& names, int64_t frame_id, double stall_s, const ServiceContext& ctx) {
    std::unique_lock<std::mutex> lock(mutex_);
    const auto start = Clock::now();
    while (!ctx.stopRequested()) {
      if (!restarted_.empty()) return Wait::kRestarted;
      if (minAcked(names) >= frame_id) return Wait::kAcked;
      if (secondsSince(std::max(start, last_ack_)) > stall_s) return Wait::kStalled;
      changed_.wait_for(lock, std::chrono::milliseconds(50));
    }
    return Wait::kStopped;
  }

  // Seconds since the last acknowledgement that moved any consumer forward.
  double silentSeconds() {
    std::lock_guard<std::mutex> lock(mutex_);
    return secondsSince(last_ack_);
  }
  void progressed() {
    std::lock_guard<std::mutex> lock(mutex_);
    last_ack_ = Clock::now();
  }
  // The first service in `names` that has not acknowledged `frame_id`.
  std::string lagging(const std::vector<std::string>& names, int64_t frame_id) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& n : names) {
      if (ackedLocked(n) < frame_id) return n;
    }
    return "";
  }

  int64_t acked(const std::string& name) {
    std::lock_guard<std::mutex> lock(mutex_);
    return ackedLocked(name);
  }
  void setAcked(const std::string& name, int64_t frame_id) {
    std::lock_guard<std::mutex> lock(mutex_);
    acked_[name] = frame_id;
  }
  // The resume point the current instance of `service` announced: waits up
  // to `timeout_s` for it; nullopt when it keeps no state (none came).
  std::optional<int64_t> resumePoint(const std::string& service, double timeout_s, const ServiceContext& ctx) {
    std::unique_lock<std::mutex> lock(mutex_);
    const auto deadline = Clock::now() + std::chrono::duration<double>(timeout_s);
    while (!ctx.stopRequested()) {
      auto it = resume_points_.find({service, pids_[service]});
      if (it != resume_points_.end()) return it->second;
      if (Clock::now() > deadline) break;
      changed_.wait_for(lock, std::chrono::milliseconds(50));
    }
    return std::nullopt;
  }
  std::set<std::string> takeRestarts() {
    std::lock_guard<std::mutex> lock(mutex_);
    std::set<std::string> r;
    r.swap(restarted_);
    return r;
  }

 private:
  int64_t ackedLocked(const std::string& name) const {
    auto it = acked_.find(name);
    return it == acked_.end() ? -1 : it->second;
  }
  int64_t minAcked(const std::vector<std::string>& names) const {
    int64_t m = INT64_MAX;
    for (const auto& n : names) m = std::min(m, ackedLocked(n));
    return m;
  }
  std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, std::string> hosts_;
  std::map<std::string, int> pids_;
  std::map<std::string, int64_t> acked_;
  std::set<std::string> restarted_;
  std::map<std::pair<std::string, int>, int64_t> resume_points_;  // (service, pid) -> first missing frame
  Clock::time_point last_ack_ = Clock::now();
};

// Recorded duration of `n` frames from `first`: their time span plus one frame
// period (1000 frames at 30 Hz are 33.3 s of data).
double sequenceSeconds(const TumDataset& dataset, size_t first, size_t n) {
  if (n < 2) return 0.0;
  const double span = dataset.timestamp(first + n - 1) - dataset.timestamp(first);
  return span + span / static_cast<double>(n - 1);
}

std::string thisHost() {
  char buf[256] = {0};
  gethostname(buf, sizeof(buf) - 1);
  return buf;
}

}  // namespace

PlayerParams PlayerParams::fromConfig(const Config& config, const std::string& dataset) {
  PlayerParams p;
  p.dataset = dataset;
  const std::string rate = config.getString("player.rate");
  if (rate != "max") {
    try {
      p.rate = std::stod(rate);
    } catch (const std::exception&) {
      p.rate = -1;
    }
    if (!(p.rate > 0)) throw Error("player.rate '" + rate + "' must be \"max\" or a positive multiple of the recorded rate");
  }
  p.wait_for = config.getStringList("player.wait_for");
  p.wait_timeout_s = config.getDouble("player.wait_timeout_s");
  p.max_frames = config.getInt("player.max_frames");
  p.first_frame = config.getInt("player.first_frame");
  p.camera = config.getString("player.camera");
  p.transport_mode = config.getString("transport.mode");
  p.segment = config.getString("transport.segment");
  p.slots = config.getInt("transport.slots");
  p.max_width = config.getInt("transport.max_width");
  p.max_height = config.getInt("transport.max_height");
  if (p.transport_mode != "auto") parseTransportMode(p.transport_mode);
  return p;
}

void runPlayer(ServiceContext& ctx, const PlayerParams& params) {
  DatasetOptions options;
  options.max_frames = params.max_frames > 0 ? params.first_frame + params.max_frames : 0;
  if (!params.camera.empty()) options.intrinsics_override = loadIntrinsics(params.camera);
  const TumDataset dataset(params.dataset, options);
  if (params.first_frame < 0 || static_cast<size_t>(params.first_frame) >= dataset.size()) {
    throw Error("player.first_frame " + std::to_string(params.first_frame) + " is beyond the " +
                std::to_string(dataset.size()) + " frames of " + params.dataset);
  }
  const int64_t first = params.first_frame;
  const int64_t end = static_cast<int64_t>(dataset.size());  // one past the last frame id
  const size_t count = dataset.size() - static_cast<size_t>(first);
  spdlog::info("dataset {}: {} frames, {}x{}, {:.1f} s", params.dataset, count, dataset.intrinsics().width,
               dataset.intrinsics().height, dataset.timestamp(dataset.size() - 1) - dataset.timestamp(first));

  ConsumerWatch watch(ctx.bus());
  PeerWatch peers(ctx.bus());
  StopThreadsOnExit stop_threads(ctx);  // before `watch` dies: its handlers run on the bus thread
  if (!params.wait_for.empty()) {
    ctx.setState("waiting for consumers");
    const auto missing = watch.waitForHeartbeats(params.wait_for, params.wait_timeout_s, ctx);
    if (!missing.empty()) {
      throw Error("no heartbeat from rekon-" + missing.front() + " within " + std::to_string(int(params.wait_timeout_s)) +
                  " s; start it, or remove it from player.wait_for");
    }
  }
  TransportMode mode;
  if (params.transport_mode == "auto") {
    const bool local = !params.wait_for.empty() && watch.allOnHost(params.wait_for, thisHost());
    mode = local ? TransportMode::kShm : TransportMode::kLcm;
    spdlog::info("transport auto: {}", local ? "shm (every consumer is on this host)" : "inline LCM");
  } else {
    mode = parseTransportMode(params.transport_mode);
  }
  FrameSender sender(ctx.bus(), mode, params.segment, {params.slots, params.max_width, params.max_height});
  // Keep at most slots-1 frames unacknowledged so the ring never overwrites
  // a frame a consumer has not read; inline frames (~0.5 MB each) keep two
  // in flight so the receivers' UDP buffers never overflow.
  const int in_flight = mode == TransportMode::kShm ? sender.slots() - 1 : 2;
  const bool acked_pacing = !params.wait_for.empty();

  int64_t newest_sent = -1;
  int64_t resent = 0, rewinds = 0;
  auto sendFrame = [&](int64_t id) {
    const size_t i = static_cast<size_t>(id);
    const EncodedFrame encoded = dataset.loadEncoded(i);
    const RgbdFrame frame = dataset.decode(i, encoded);  // validates the files before anyone sees them
    sender.send(frame, dataset.intrinsics(), &encoded);
    newest_sent = std::max(newest_sent, id);
  };
  // Waits until every consumer acknowledged `frame_id`. Re-sends the newest
  // frame while acknowledgements stall; false when a consumer restarted (the
  // caller rewinds first). Throws when they stay silent beyond wait_timeout_s.
  auto waitForAcks = [&](int64_t frame_id) {
    while (true) {
      switch (watch.waitForAck(params.wait_for, frame_id, kResendAfterS, ctx)) {
        case ConsumerWatch::Wait::kAcked:
        case ConsumerWatch::Wait::kStopped:
          return true;
        case ConsumerWatch::Wait::kRestarted:
          return false;
        case ConsumerWatch::Wait::kStalled:
          break;
      }
      const std::string silent = watch.lagging(params.wait_for, frame_id);
      if (watch.silentSeconds() > params.wait_timeout_s) {
        throw Error("rekon-" + silent + " acknowledged no frame for " + std::to_string(int(params.wait_timeout_s)) +
                    " s (last acknowledged: " + std::to_string(watch.acked(silent)) + "); is it alive? see its log");
      }
      // A dead consumer is not helped by frames; the launcher restarts it or stops the run.
      if (newest_sent >= 0 && peers.alive(silent, 2.0)) {
        spdlog::debug("no acknowledgement from rekon-{} for {:.0f} s: sending frame {} again", silent, kResendAfterS, newest_sent);
        sendFrame(newest_sent);
        ++resent;
      }
    }
  };
  // A restarted consumer: one that announces a resume point (the mapper,
  // after the frames in its keyframe store) gets every frame from it again;
  // any other continues from the next new frame (a tracker could not
  // continue its odometry from old frames anyway).
  auto handleRestarts = [&](int64_t next) {
    for (const auto& service : watch.takeRestarts()) {
      if (std::find(params.wait_for.begin(), params.wait_for.end(), service) == params.wait_for.end()) continue;
      const std::optional<int64_t> point = newest_sent < 0 ? std::nullopt : watch.resumePoint(service, kResumePointWaitS, ctx);
      if (!point) {
        spdlog::warn("rekon-{} restarted: it continues from frame {}", service, next);
        watch.setAcked(service, next - 1);
        continue;
      }
      const int64_t resume = std::clamp(*point < 0 ? first : *point, first, next);
      // The others first read everything sent: the ring's slots are about to be reused out of order.
      std::vector<std::string> others;
      for (const auto& s : params.wait_for)
        if (s != service) others.push_back(s);
      const auto since = Clock::now();
      while (!ctx.stopRequested() && secondsSince(since) < params.wait_timeout_s &&
             watch.waitForAck(others, newest_sent, kResendAfterS, ctx) == ConsumerWatch::Wait::kStalled) {
      }
      spdlog::warn("rekon-{} restarted: sending frames {}..{} again (its resume point)", service, resume, next - 1);
      watch.setAcked(service, resume - 1);
      watch.progressed();
      ++rewinds;
      next = resume;
    }
    return next;
  };
  // Sends frames [from, to): paced by acknowledgements, or by the recorded
  // rate; returns where a restart rewound to (or `to`).
  const auto start = Clock::now();
  const double t0 = dataset.timestamp(static_cast<size_t>(first));
  auto last_report = start;
  int64_t sent = 0;
  auto play = [&](int64_t from, int64_t to) {
    for (int64_t id = from; id < to && !ctx.stopRequested();) {
      const int64_t rewound = handleRestarts(id);
      if (rewound != id) {
        id = rewound;
        continue;
      }
      const bool replaying = id <= newest_sent;
      if (params.rate > 0 && !replaying) {
        const auto due = start + std::chrono::duration_cast<Clock::duration>(
                                     std::chrono::duration<double>((dataset.timestamp(static_cast<size_t>(id)) - t0) / params.rate));
        std::this_thread::sleep_until(due);
      } else if (acked_pacing && !waitForAcks(id - in_flight)) {
        continue;  // a consumer restarted: handled at the top
      }
      sendFrame(id);
      ctx.setLastFrame(id);
      if (replaying) ++resent;
      else ++sent;
      ++id;
      if (secondsSince(last_report) > 2.0 || id == end) {
        last_report = Clock::now();
        const double elapsed = secondsSince(start);
        spdlog::info("frame {}/{} ({:.0f} %), {:.1f} frames/s", sent, count, 100.0 * static_cast<double>(sent) / count,
                     sent / elapsed);
      }
    }
  };
  rekon_msgs::end_of_stream_t eos{};
  // Plays (again) up to the end, lets consumers finish the frames in flight,
  // then announces the end; repeated while a restart rewinds.
  auto playToEnd = [&](int64_t from) {
    int64_t next = from;
    while (!ctx.stopRequested()) {
      play(next, end);
      if (ctx.stopRequested()) return;
      if (acked_pacing && !waitForAcks(newest_sent)) {
        next = handleRestarts(end);
        continue;
      }
      break;
    }
    eos.last_frame_id = newest_sent;
    eos.frames = sent;
    eos.duration_s = sequenceSeconds(dataset, static_cast<size_t>(first), static_cast<size_t>(sent));
    // Repeated: an end-of-stream lost on the wire must not leave a consumer waiting.
    for (int k = 0; k < 3; ++k) {
      ctx.bus().publish(channel::kEndOfStream, eos);
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  };

  ctx.setState("playing");
  playToEnd(first);
  const double wall = secondsSince(start);
  spdlog::info("played {} frames in {:.2f} s ({:.1f} frames/s, transport {})", sent, wall,
               static_cast<double>(sent) / std::max(wall, 1e-9), mode == TransportMode::kShm ? "shm" : "lcm");
  ctx.stats()
      .set("frames", static_cast<long long>(sent))
      .set("sequence_seconds", eos.duration_s)
      .set("wall_seconds", wall)
      .set("transport", mode == TransportMode::kShm ? "shm" : "lcm");

  // Stay until the consumers are done: one restarted meanwhile gets its frames
  // again (from the ring, which lives as long as this function).
  ctx.setState("lingering");
  while (acked_pacing && !ctx.stopRequested() && !peers.finished(params.wait_for, PeerWatch::kSilenceS)) {
    const int64_t next = handleRestarts(end);
    if (next != end) playToEnd(next);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ctx.stats().set("frames_sent_again", static_cast<long long>(resent)).set("rewinds", static_cast<long long>(rewinds));
}

}  // namespace rekon
