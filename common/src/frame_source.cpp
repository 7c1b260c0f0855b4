#include "rekon/common/frame_source.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <exception>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <thread>
#include <utility>

#include "rekon/common/csv_log.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/latency_histogram.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon {

void waitForConsumers(ServiceContext& ctx, ConsumerWatch& watch, const std::vector<std::string>& consumers,
                      double timeout_s, const std::string& wait_for_key) {
  if (consumers.empty()) return;
  ctx.setState("waiting for consumers");
  const auto missing = watch.waitForHeartbeats(consumers, timeout_s, ctx);
  if (!missing.empty()) {
    throw Error("no heartbeat from rekon-" + missing.front() + " within " + std::to_string(int(timeout_s)) +
                " s; start it, or remove it from " + wait_for_key);
  }
}

TransportMode chooseTransport(const std::string& mode, const std::vector<std::string>& consumers, ConsumerWatch& watch) {
  if (mode != "auto") return parseTransportMode(mode);
  const bool local = !consumers.empty() && watch.allOnHost(consumers, hostName());
  spdlog::info("transport auto: {}", local ? "shm (every consumer is on this host)" : "inline LCM");
  return local ? TransportMode::kShm : TransportMode::kLcm;
}

void announceEndOfStream(Bus& bus, const rekon_msgs::end_of_stream_t& eos) {
  for (int k = 0; k < 3; ++k) {
    bus.publish(channel::kEndOfStream, eos);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

void lingerAfterLiveEnd(ServiceContext& ctx, ConsumerWatch& watch, const PeerWatch& peers,
                        const std::vector<std::string>& consumers, const rekon_msgs::end_of_stream_t& eos) {
  ctx.setState("lingering");
  while (!ctx.stopRequested() && !peers.finished(consumers)) {
    for (const auto& service : watch.takeRestarts()) {
      if (std::find(consumers.begin(), consumers.end(), service) == consumers.end()) continue;
      spdlog::warn("rekon-{} restarted after the end of the stream: announcing the end again", service);
      announceEndOfStream(ctx.bus(), eos);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

namespace {

using Clock = std::chrono::steady_clock;
// Without any acknowledgement for this long the newest sent frame goes out
// again (as the player does): a frame or its acknowledgements were lost.
constexpr double kResendAfterS = 1.0;

// A frame as sent, kept to be sent again with the intrinsics it went with
// (`State::k` belongs to the waiting frame and changes under the lock).
struct SentFrame {
  RgbdFrame frame;
  Intrinsics k;
};

}  // namespace

struct LiveOutlet::State {
  ServiceContext& ctx;
  FrameSender& sender;
  ConsumerWatch& watch;
  const std::vector<std::string> consumers;
  const size_t in_flight;

  mutable std::mutex mutex;
  std::condition_variable wake;
  std::optional<RgbdFrame> waiting;
  Intrinsics k;  // the waiting frame's
  std::exception_ptr error;  // what ended the sender thread, until offer() or finish() throws it
  bool stopping = false;
  Counts counts;
  std::deque<int64_t> unacked;                  // ids sent, oldest first, not yet known to be acknowledged
  std::map<int64_t, Clock::time_point> capture;  // capture time of each frame sent and not yet tracked
  LatencyHistogram latency;
  std::optional<CsvLog> latency_csv;  // <out>/<service>_latency.csv; none without --out
  Clock::time_point started = Clock::now();
  std::set<std::string> absent;  // consumers left out of the window (sender thread only)
  std::map<std::string, int64_t> rejoining;  // restarted consumers: the newest frame sent at their restart
  std::thread thread;  // the sender; touches `sender` and `watch` outside the lock

  State(ServiceContext& c, FrameSender& s, ConsumerWatch& w, std::vector<std::string> names, int n)
      : ctx(c), sender(s), watch(w), consumers(std::move(names)), in_flight(static_cast<size_t>(std::max(1, n))) {
    if (!ctx.outDir().empty())
      latency_csv.emplace((std::filesystem::path(ctx.outDir()) / (ctx.name() + "_latency.csv")).string(),
                          "frame_id,captured_s,latency_ms");
  }

  void onTracked(const rekon_msgs::tracked_frame_t& msg) {
    std::lock_guard<std::mutex> lock(mutex);
    const auto it = capture.find(msg.frame_id);
    if (it != capture.end()) record(msg.frame_id, it->second);
    capture.erase(capture.begin(), capture.upper_bound(msg.frame_id));
  }

  // One capture-to-pose latency: into the histogram and, with --out, a row of the CSV.
  void record(int64_t frame_id, Clock::time_point captured) {
    const double ms = std::chrono::duration<double, std::milli>(Clock::now() - captured).count();
    latency.add(ms);
    if (latency_csv) latency_csv->row(frame_id, std::chrono::duration<double>(captured - started).count(), ms);
  }

  // The consumers to wait for: those not restarting nor silent for
  // lifecycle.silence_s. A killed one whose restart is still "starting" (a
  // mapper rebuilding its volume takes tens of seconds) must not hold the
  // others' frames: a tracker without frames that long is lost (the 3-lap
  // corridor's chaos run lost 30 s and put lap 3 15 m away). Each change is
  // one log line.
  // A restarted one is left out too until it acknowledges a frame sent after
  // its restart: a restarted mapper refuses frames for 5 s while it waits for
  // a rewind that a live source never makes.
  std::vector<std::string> presentConsumers() {
    std::vector<std::string> present;
    for (const auto& c : watch.present(consumers, ctx.lifecycle().silence_s)) {
      const auto r = rejoining.find(c);
      if (r != rejoining.end() && watch.acked(c) <= r->second) continue;
      if (r != rejoining.end()) rejoining.erase(r);
      present.push_back(c);
    }
    for (const auto& c : consumers) {
      const bool is_present = std::find(present.begin(), present.end(), c) != present.end();
      if (!is_present && absent.insert(c).second)
        spdlog::warn("rekon-{} is restarting or silent: the other consumers get the frames without it until it "
                     "acknowledges one", c);
      if (is_present && absent.erase(c) > 0) spdlog::info("rekon-{} is back: it acknowledges frames again", c);
    }
    return present;
  }

  // A live source cannot rewind: a restarted consumer goes on from the next frame.
  void noteRestarts() {
    for (const auto& service : watch.takeRestarts()) {
      spdlog::warn("rekon-{} restarted: it continues from the next frame (a live source cannot send old ones)", service);
      watch.setAcked(service, counts.newest_sent);
      rejoining[service] = counts.newest_sent;
    }
  }

  // True when fewer than in_flight sent frames are unacknowledged by the
  // consumers present; waits (a while) for an acknowledgement otherwise,
  // sending the newest frame again when they stall.
  bool room(const std::optional<SentFrame>& newest_sent) {
    int64_t oldest_in_window;
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (consumers.empty()) return true;  // nobody acknowledges: nothing to wait for
      if (unacked.size() < in_flight) return true;
      oldest_in_window = unacked[unacked.size() - in_flight];
    }
    noteRestarts();
    const std::vector<std::string> present = presentConsumers();
    if (present.empty()) return true;
    switch (watch.waitForAck(present, oldest_in_window, kResendAfterS, ctx, true)) {
      case ConsumerWatch::Wait::kAcked: {
        std::lock_guard<std::mutex> lock(mutex);
        while (!unacked.empty() && unacked.front() <= oldest_in_window) unacked.pop_front();
        return unacked.size() < in_flight;
      }
      case ConsumerWatch::Wait::kRestarted:  // noted by the next call
        return false;
      case ConsumerWatch::Wait::kStalled:
        if (newest_sent) {
          spdlog::debug("no acknowledgement for {:.0f} s: sending frame {} again", kResendAfterS, newest_sent->frame.id);
          sender.send(newest_sent->frame, newest_sent->k);
        }
        return false;
      case ConsumerWatch::Wait::kStopped:
        return false;
    }
    return false;
  }

  // The sender thread: an exception ends it, held for offer() or finish() to
  // throw on the source's thread (whose service logs it as its one line and
  // stops cleanly); a stop is requested so that the source stops offering.
  void run() {
    try {
      sendUntilStopped();
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex);
      error = std::current_exception();
      ctx.requestStop();
    }
  }

  void sendUntilStopped() {
    std::optional<SentFrame> newest_sent;
    while (true) {
      {
        std::unique_lock<std::mutex> lock(mutex);
        wake.wait(lock, [&] { return waiting.has_value() || stopping; });
        if (!waiting || ctx.stopRequested()) return;
      }
      if (!room(newest_sent)) continue;  // the waiting frame may have been replaced meanwhile
      {
        std::lock_guard<std::mutex> lock(mutex);
        newest_sent = SentFrame{std::move(*waiting), k};
        waiting.reset();
      }
      sender.send(newest_sent->frame, newest_sent->k);
      ctx.setLastFrame(newest_sent->frame.id);
      std::lock_guard<std::mutex> lock(mutex);
      unacked.push_back(newest_sent->frame.id);
      ++counts.sent;
      counts.newest_sent = newest_sent->frame.id;
      ctx.setLive("frames_sent", static_cast<double>(counts.sent));
    }
  }

  // Throws the sender thread's exception, once. Call with `mutex` held.
  void throwSenderError() {
    if (error) std::rethrow_exception(std::exchange(error, nullptr));
  }
};

LiveOutlet::LiveOutlet(ServiceContext& ctx, FrameSender& sender, ConsumerWatch& watch,
                       std::vector<std::string> consumers, int in_flight)
    : state_(std::make_shared<State>(ctx, sender, watch, std::move(consumers), in_flight)) {
  std::weak_ptr<State> weak = state_;
  ctx.bus().subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFrames, [weak](const rekon_msgs::tracked_frame_t& m) {
    if (auto state = weak.lock()) state->onTracked(m);
  });
  // Both counts from the start, in the live STATS as in stats.json.
  for (const char* key : {"frames_captured", "frames_sent", "frames_dropped", "frames_skipped_late"}) ctx.setLive(key, 0.0);
  state_->thread = std::thread([s = state_.get()] { s->run(); });
}

LiveOutlet::~LiveOutlet() {
  {
    std::lock_guard<std::mutex> lock(state_->mutex);
    state_->stopping = true;
    state_->waiting.reset();
  }
  state_->wake.notify_all();
  if (state_->thread.joinable()) state_->thread.join();
  // Destroyed before offer() or finish() could pass the sender's exception on
  // (the source failed too): it still gets its one line.
  std::lock_guard<std::mutex> lock(state_->mutex);
  try {
    state_->throwSenderError();
  } catch (...) {
    spdlog::error("{}", currentExceptionLine());
  }
}

void LiveOutlet::offer(RgbdFrame frame, const Intrinsics& k, double age_s) {
  const auto captured = Clock::now() - std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(std::clamp(age_s, 0.0, 10.0)));
  {
    std::lock_guard<std::mutex> lock(state_->mutex);
    state_->throwSenderError();
    if (state_->waiting) ++state_->counts.dropped;
    ++state_->counts.offered;
    state_->capture[frame.id] = captured;
    if (state_->capture.size() > 4096) state_->capture.erase(state_->capture.begin());  // poses that never came
    state_->waiting = std::move(frame);
    state_->k = k;
    state_->ctx.setLive("frames_captured", static_cast<double>(state_->counts.offered));
    state_->ctx.setLive("frames_dropped", static_cast<double>(state_->counts.dropped));
  }
  state_->wake.notify_all();
}

void LiveOutlet::skippedLate(int64_t n) {
  if (n <= 0) return;
  std::lock_guard<std::mutex> lock(state_->mutex);
  state_->counts.skipped_late += n;
  state_->ctx.setLive("frames_skipped_late", static_cast<double>(state_->counts.skipped_late));
}

void LiveOutlet::finish(double timeout_s) {
  // Let the sender pass on the frame still waiting, if the consumers take it.
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_s));
  auto waiting = [&] {
    std::lock_guard<std::mutex> lock(state_->mutex);
    return state_->waiting.has_value();
  };
  while (waiting() && Clock::now() < deadline && !state_->ctx.stopRequested()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  {
    std::lock_guard<std::mutex> lock(state_->mutex);
    if (state_->waiting) ++state_->counts.dropped;
    state_->ctx.setLive("frames_dropped", static_cast<double>(state_->counts.dropped));
    state_->waiting.reset();
    state_->stopping = true;
  }
  state_->wake.notify_all();
  if (state_->thread.joinable()) state_->thread.join();
  {
    std::lock_guard<std::mutex> lock(state_->mutex);
    state_->throwSenderError();
  }
  const int64_t last = counts().newest_sent;
  const double left_s = std::chrono::duration<double>(deadline - Clock::now()).count();
  if (last >= 0 && left_s > 0) state_->watch.waitForAck(state_->consumers, last, left_s, state_->ctx);
}

LiveOutlet::Counts LiveOutlet::counts() const {
  std::lock_guard<std::mutex> lock(state_->mutex);
  return state_->counts;
}

void LiveOutlet::writeStats(JsonObject& stats) const {
  std::lock_guard<std::mutex> lock(state_->mutex);
  const Counts& c = state_->counts;
  stats.set("frames_captured", static_cast<long long>(c.offered))
      .set("frames_sent", static_cast<long long>(c.sent))
      .set("frames_dropped", static_cast<long long>(c.dropped))
      .set("frames_skipped_late", static_cast<long long>(c.skipped_late));
  const LatencyHistogram& h = state_->latency;
  stats.set("latency_samples", static_cast<long long>(h.count()));
  if (h.count() > 0) stats.set("latency_ms_p50", h.quantile(0.5)).set("latency_ms_p95", h.quantile(0.95));
}

struct SourceCountsLog::State {
  std::optional<CsvLog> csv;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  double next_row_s = 1.0, ms = 0;
  int64_t made = 0;
};

SourceCountsLog::SourceCountsLog(const std::string& out_dir) : state_(std::make_unique<State>()) {
  if (!out_dir.empty())
    state_->csv.emplace(out_dir + "/source_counts.csv", "seconds,frames_due,sent,dropped,skipped_late,render_ms_mean");
}

SourceCountsLog::~SourceCountsLog() = default;

void SourceCountsLog::frameMade(double ms) {
  state_->ms += ms;
  ++state_->made;
}

void SourceCountsLog::row(int64_t due, const LiveOutlet::Counts& c, bool last_row) {
  State& s = *state_;
  const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - s.start).count();
  if (!s.csv || (t < s.next_row_s && !last_row)) return;
  s.next_row_s = std::floor(t) + 1.0;
  s.csv->row(t, due, c.sent, c.dropped, c.skipped_late, s.made > 0 ? s.ms / static_cast<double>(s.made) : 0.0);
  s.ms = 0;
  s.made = 0;
}

}  // namespace rekon
