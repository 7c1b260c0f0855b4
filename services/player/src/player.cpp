#include "rekon/player/player.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <thread>

#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"

namespace rekon {
namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// What the player hears from its consumers: who is alive where, and how far
// each has acknowledged.
class ConsumerWatch {
 public:
  explicit ConsumerWatch(Bus& bus) {
    bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [this](const rekon_msgs::heartbeat_t& hb) {
      // A service counts once it has subscribed to its inputs ("running");
      // frames sent while it is still "starting" would be lost to it.
      if (hb.state == "starting") return;
      std::lock_guard<std::mutex> lock(mutex_);
      hosts_[hb.service] = hb.host;
      changed_.notify_all();
    });
    bus.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [this](const rekon_msgs::frame_ack_t& ack) {
      std::lock_guard<std::mutex> lock(mutex_);
      auto& acked = acked_[ack.service];
      acked = std::max(acked, ack.frame_id);
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

  // Waits until every service in `names` acknowledged frame `frame_id`.
  // Returns the first service that stayed silent beyond `timeout_s`, or "".
  std::string waitForAck(const std::vector<std::string>& names, int64_t frame_id, double timeout_s,
                         const ServiceContext& ctx) {
    std::unique_lock<std::mutex> lock(mutex_);
    auto last_progress = Clock::now();
    int64_t last_min = minAcked(names);
    while (minAcked(names) < frame_id && !ctx.stopRequested()) {
      changed_.wait_for(lock, std::chrono::milliseconds(50));
      const int64_t m = minAcked(names);
      if (m != last_min) {
        last_min = m;
        last_progress = Clock::now();
      } else if (secondsSince(last_progress) > timeout_s) {
        for (const auto& n : names) {
          if (acked_.count(n) == 0 || acked_[n] < frame_id) return n;
        }
      }
    }
    return "";
  }

  int64_t acked(const std::string& name) {
    std::lock_guard<std::mutex> lock(mutex_);
    return acked_.count(name) ? acked_[name] : -1;
  }

 private:
  int64_t minAcked(const std::vector<std::string>& names) {
    int64_t m = INT64_MAX;
    for (const auto& n : names) m = std::min(m, acked_.count(n) ? acked_[n] : int64_t{-1});
    return m;
  }
  std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, std::string> hosts_;
  std::map<std::string, int64_t> acked_;
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
  const size_t first = static_cast<size_t>(params.first_frame);
  const size_t count = dataset.size() - first;
  spdlog::info("dataset {}: {} frames, {}x{}, {:.1f} s", params.dataset, count, dataset.intrinsics().width,
               dataset.intrinsics().height, dataset.timestamp(dataset.size() - 1) - dataset.timestamp(first));

  ConsumerWatch watch(ctx.bus());
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

  ctx.setState("playing");
  const auto start = Clock::now();
  auto last_report = start;
  const double t0 = dataset.timestamp(first);
  size_t sent = 0;
  for (size_t i = first; i < dataset.size() && !ctx.stopRequested(); ++i) {
    const EncodedFrame encoded = dataset.loadEncoded(i);
    const RgbdFrame frame = dataset.decode(i, encoded);  // validates the files before anyone sees them
    if (params.rate > 0) {
      const auto due = start + std::chrono::duration_cast<Clock::duration>(
                                   std::chrono::duration<double>((dataset.timestamp(i) - t0) / params.rate));
      std::this_thread::sleep_until(due);
    } else if (!params.wait_for.empty()) {
      // Keep at most slots-1 frames unacknowledged so the ring never overwrites
      // a frame a consumer has not read; inline frames (~0.5 MB each) keep two
      // in flight so the receivers' UDP buffers never overflow.
      const int in_flight = mode == TransportMode::kShm ? sender.slots() - 1 : 2;
      const int64_t must_be_acked = frame.id - in_flight;
      const std::string silent = watch.waitForAck(params.wait_for, must_be_acked, params.wait_timeout_s, ctx);
      if (!silent.empty()) {
        throw Error("rekon-" + silent + " acknowledged no frame for " + std::to_string(int(params.wait_timeout_s)) +
                    " s (last acknowledged: " + std::to_string(watch.acked(silent)) + "); is it alive? see its log");
      }
    }
    sender.send(frame, dataset.intrinsics(), &encoded);
    ctx.setLastFrame(frame.id);
    ++sent;
    if (secondsSince(last_report) > 2.0 || i + 1 == dataset.size()) {
      last_report = Clock::now();
      const double elapsed = secondsSince(start);
      spdlog::info("frame {}/{} ({:.0f} %), {:.1f} frames/s", sent, count, 100.0 * sent / count, sent / elapsed);
    }
  }
  // Let consumers finish the frames in flight before the end is announced.
  if (params.rate <= 0 && !params.wait_for.empty() && sent > 0 && !ctx.stopRequested()) {
    watch.waitForAck(params.wait_for, static_cast<int64_t>(first + sent - 1), params.wait_timeout_s, ctx);
  }
  rekon_msgs::end_of_stream_t eos{};
  eos.last_frame_id = static_cast<int64_t>(first + sent) - 1;
  eos.frames = static_cast<int64_t>(sent);
  eos.duration_s = sequenceSeconds(dataset, first, sent);
  // Repeated: an end-of-stream lost on the wire must not leave a consumer waiting.
  for (int k = 0; k < 3; ++k) {
    ctx.bus().publish(channel::kEndOfStream, eos);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  const double wall = secondsSince(start);
  spdlog::info("played {} frames in {:.2f} s ({:.1f} frames/s, transport {})", sent, wall, sent / std::max(wall, 1e-9),
               mode == TransportMode::kShm ? "shm" : "lcm");
  ctx.stats()
      .set("frames", static_cast<long long>(sent))
      .set("sequence_seconds", eos.duration_s)
      .set("wall_seconds", wall)
      .set("transport", mode == TransportMode::kShm ? "shm" : "lcm");
  // The ring must outlive the consumers' last reads: `sender` (and the segment)
  // goes when this function returns, after every frame was acknowledged.
}

}  // namespace rekon
