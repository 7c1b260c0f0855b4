#include "rekon/player/player.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <optional>
#include <thread>

#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_source.hpp"
#include "decode_ahead.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"

namespace rekon {
namespace {

using Clock = ConsumerWatch::Clock;

// Without any acknowledgement for this long, the newest frame is sent again:
// the frame or its acknowledgements were lost (lcm.drop_fraction, a full
// socket buffer), and an acknowledgement of the newest covers every older one.
constexpr double kResendAfterS = 1.0;
// A restarted consumer that keeps state sends its resume point as it starts
// and once a second after; one not heard within this long keeps none.
constexpr double kResumePointWaitS = 3.0;

// Recorded duration of `n` frames from `first`: their time span plus one frame
// period (1000 frames at 30 Hz are 33.3 s of data).
double sequenceSeconds(const TumDataset& dataset, size_t first, size_t n) {
  if (n < 2) return 0.0;
  const double span = dataset.timestamp(first + n - 1) - dataset.timestamp(first);
  return span + span / static_cast<double>(n - 1);
}

TumDataset openDataset(const PlayerParams& params) {
  DatasetOptions options;
  options.max_frames = params.max_frames > 0 ? params.first_frame + params.max_frames : 0;
  if (!params.camera.empty()) options.intrinsics_override = loadIntrinsics(params.camera);
  TumDataset dataset(params.dataset, options);
  if (params.first_frame < 0 || static_cast<size_t>(params.first_frame) >= dataset.size()) {
    throw Error("player.first_frame " + std::to_string(params.first_frame) + " is beyond the " +
                std::to_string(dataset.size()) + " frames of " + params.dataset);
  }
  return dataset;
}

// One playback of a dataset: sends frames [first, end) paced by the
// consumers' acknowledgements or by the recorded rate, sends frames again
// for a restarted consumer, announces the end, and stays until the
// consumers are done.
class Player {
 public:
  Player(ServiceContext& ctx, const PlayerParams& params)
      : ctx_(ctx), params_(params), dataset_(openDataset(params)), first_(params.first_frame),
        end_(static_cast<int64_t>(dataset_.size())), count_(dataset_.size() - static_cast<size_t>(first_)),
        ahead_(dataset_, params.decode_threads, end_), watch_(ctx.bus()), peers_(ctx.bus(), ctx.lifecycle()), stop_threads_(ctx),
        consumers_(params.wait_for), acked_pacing_(!params.wait_for.empty()) {
    spdlog::info("dataset {}: {} frames, {}x{}, {:.1f} s", params.dataset, count_, dataset_.intrinsics().width,
                 dataset_.intrinsics().height, dataset_.timestamp(dataset_.size() - 1) - dataset_.timestamp(first_));
  }

  void run() {
    if (params_.restarted) forgetFinishedConsumers();
    else waitForConsumers(ctx_, watch_, consumers_, params_.wait_timeout_s, "player.wait_for");
    if (params_.restarted && consumers_.empty() && !params_.wait_for.empty()) {
      spdlog::info("every consumer has finished with the stream: nothing left to play");
      return;
    }
    mode_ = chooseTransport(params_.transport_mode, consumers_, watch_);
    sender_.emplace(ctx_.bus(), mode_, params_.segment, FrameRingLayout{params_.slots, params_.max_width, params_.max_height});
    // Keep at most slots-1 frames unacknowledged so the ring never overwrites
    // a frame a consumer has not read; inline frames (~0.5 MB each) keep two
    // in flight so the receivers' UDP buffers never overflow.
    in_flight_ = mode_ == TransportMode::kShm ? sender_->slots() - 1 : 2;
    const int64_t from = params_.restarted ? whereTheConsumersAre() : first_;
    start_ = playbackStart(from);
    last_report_ = Clock::now();
    ctx_.setState("playing");
    if (params_.live) playLive(from);
    else playToEnd(from);
    reportPlayed();
    linger();
    ctx_.stats()
        .set("frames_sent_again", static_cast<long long>(resent_))
        .set("rewinds", static_cast<long long>(rewinds_))
        .set("frames_decoded_unused", static_cast<long long>(ahead_.unused()));
    if (params_.restarted) ctx_.stats().set("restarted_at_frame", static_cast<long long>(from));
  }

 private:
  // Consumers a restarted player does not hear within lifecycle.silence_s
  // have finished with the stream while it was dead (its end was announced)
  // and exited: it no longer waits for them (the launcher restarts one that
  // died, whose heartbeat then comes in time).
  void forgetFinishedConsumers() {
    const double silence_s = ctx_.lifecycle().silence_s;
    for (const auto& gone : watch_.waitForHeartbeats(consumers_, silence_s, ctx_)) {
      spdlog::warn("rekon-{} was not heard within {:.0f} s of this restart: it has finished; not waiting for it", gone,
                   silence_s);
      std::erase(consumers_, gone);
    }
  }

  // A restarted player (player.restarted: the launcher restarts a killed
  // one) goes on where its consumers are: after the oldest of the newest
  // frames they said they have (their heartbeats; waitForConsumers heard one
  // of each). What one had beyond that comes again and is taken for a copy.
  // The frames before count as played (by the killed instance).
  int64_t whereTheConsumersAre() {
    if (consumers_.empty()) {
      spdlog::warn("restarted without consumers to ask where they are (player.wait_for is empty): playing from frame {}",
                   first_);
      return first_;
    }
    int64_t from = end_;
    for (const auto& s : consumers_) {
      const int64_t last = watch_.lastFrame(s);
      watch_.setAcked(s, last);
      from = std::min(from, last + 1);
    }
    from = std::clamp(from, first_, end_);
    newest_sent_ = from - 1;
    played_before_ = from - first_;
    spdlog::warn("restarted: the consumers have the frames up to {}; going on from frame {}", from - 1, from);
    return from;
  }

  // When frame first_ went out, on the steady clock (CLOCK_MONOTONIC: one for
  // every process of this host): the first instance writes it beside its
  // stats, and a restarted one keeps to it, so that paced frames stay on the
  // recorded clock (live: those due during the outage are skipped, as a
  // camera's would be missed). Without it, a restarted one goes on from now.
  Clock::time_point playbackStart(int64_t from) const {
    const std::string path = ctx_.outDir().empty() ? "" : ctx_.outDir() + "/player_clock.txt";
    const auto now = Clock::now();
    if (!params_.restarted) {
      if (!path.empty()) std::ofstream(path) << now.time_since_epoch().count() << "\n";
      return now;
    }
    Clock::rep ticks = 0;
    if (!path.empty() && (std::ifstream(path) >> ticks) && ticks > 0 && Clock::time_point(Clock::duration(ticks)) <= now)
      return Clock::time_point(Clock::duration(ticks));
    // `from` is end_ when the consumers had every frame (the killed instance sent them all): nothing is paced then.
    const auto since_first =
        std::chrono::duration<double>(params_.rate > 0 && from < end_ ? scheduledSeconds(from) : 0.0);
    spdlog::warn("no readable player_clock.txt in {}: frame {} goes out now, the recorded clock from there", ctx_.outDir(),
                 from);
    const Clock::time_point start = now - std::chrono::duration_cast<Clock::duration>(since_first);
    // The killed instance died before it wrote one: the next restart keeps to this clock.
    if (!path.empty()) std::ofstream(path) << start.time_since_epoch().count() << "\n";
    return start;
  }

  // Frame `id` in playing order: decoded ahead (resends decode their frame again).
  void sendFrame(int64_t id) { send(id, ahead_.take(id)); }
  void send(int64_t id, const LoadedFrame& loaded) {
    sender_->send(loaded.frame, dataset_.intrinsics(), &loaded.encoded);
    newest_sent_ = std::max(newest_sent_, id);
  }

  // Waits until every consumer acknowledged `frame_id`. Re-sends the newest
  // frame while acknowledgements stall; false when a consumer restarted (the
  // caller rewinds first). Throws when they stay silent beyond wait_timeout_s.
  bool waitForAcks(int64_t frame_id) {
    while (true) {
      switch (watch_.waitForAck(consumers_, frame_id, kResendAfterS, ctx_)) {
        case ConsumerWatch::Wait::kAcked:
        case ConsumerWatch::Wait::kStopped:
          return true;
        case ConsumerWatch::Wait::kRestarted:
          return false;
        case ConsumerWatch::Wait::kStalled:
          break;
      }
      const std::string silent = watch_.lagging(consumers_, frame_id);
      if (watch_.silentSeconds() > params_.wait_timeout_s) {
        throw Error("rekon-" + silent + " acknowledged no frame for " + std::to_string(int(params_.wait_timeout_s)) +
                    " s (last acknowledged: " + std::to_string(watch_.acked(silent)) + "); is it alive? see its log");
      }
      // A dead consumer is not helped by frames; the launcher restarts it or
      // stops the run. Nor is one whose new instance is still starting: once
      // running it gets every frame from its resume point, in order (the
      // newest first reached a restarted mapper before its resume point).
      const std::optional<PeerWatch::Peer> peer = peers_.peer(silent);
      if (newest_sent_ >= 0 && peers_.alive(silent) && peer && peer->served) {
        spdlog::debug("no acknowledgement from rekon-{} for {:.0f} s: sending frame {} again", silent, kResendAfterS,
                      newest_sent_);
        send(newest_sent_, ahead_.load(newest_sent_));
        ++resent_;
      }
    }
  }

  // A restarted consumer: one that announces a resume point (the mapper,
  // after the frames in its keyframe store) gets every frame from it again;
  // any other continues from the next new frame (a tracker could not
  // continue its odometry from old frames anyway). Returns where to go on.
  int64_t handleRestarts(int64_t next) {
    for (const auto& service : watch_.takeRestarts()) {
      if (std::find(consumers_.begin(), consumers_.end(), service) == consumers_.end()) continue;
      ++restarts_;
      const std::optional<int64_t> point =
          newest_sent_ < 0 ? std::nullopt : watch_.resumePoint(service, kResumePointWaitS, ctx_);
      if (!point) {
        spdlog::warn("rekon-{} restarted: it continues from frame {}", service, next);
        watch_.setAcked(service, next - 1);
        continue;
      }
      const int64_t resume = std::clamp(*point < 0 ? first_ : *point, first_, next);
      waitForTheOthers(service);
      spdlog::warn("rekon-{} restarted: sending frames {}..{} again (its resume point)", service, resume, next - 1);
      watch_.setAcked(service, resume - 1);
      watch_.progressed();
      ++rewinds_;
      next = resume;
    }
    return next;
  }

  // Before a rewind the consumers other than `restarted` read everything
  // sent: the ring's slots are about to be reused out of order.
  void waitForTheOthers(const std::string& restarted) {
    std::vector<std::string> others;
    for (const auto& s : consumers_)
      if (s != restarted) others.push_back(s);
    const auto since = Clock::now();
    while (!ctx_.stopRequested() && ConsumerWatch::secondsSince(since) < params_.wait_timeout_s &&
           watch_.waitForAck(others, newest_sent_, kResendAfterS, ctx_) == ConsumerWatch::Wait::kStalled) {
    }
  }

  // Frame `id`'s recorded time after the first one, divided by the rate.
  double scheduledSeconds(int64_t id) const {
    return (dataset_.timestamp(static_cast<size_t>(id)) - dataset_.timestamp(static_cast<size_t>(first_))) / params_.rate;
  }

  // Sleeps until frame `id`'s recorded time (divided by the rate) after the start.
  void sleepUntilRecorded(int64_t id) const {
    std::this_thread::sleep_until(start_ + std::chrono::duration_cast<Clock::duration>(
                                               std::chrono::duration<double>(scheduledSeconds(id))));
  }

  // Sends frames [from, to): paced by acknowledgements, and by the recorded
  // rate when one is set (never ahead of it, but behind it when the
  // consumers are slower).
  void play(int64_t from, int64_t to) {
    for (int64_t id = from; id < to && !ctx_.stopRequested();) {
      const int64_t rewound = handleRestarts(id);
      if (rewound != id) {
        id = rewound;
        continue;
      }
      const bool replaying = id <= newest_sent_;
      if (params_.rate > 0 && !replaying) sleepUntilRecorded(id);
      // (Frames before the first one were never sent: nothing to wait for.)
      if (acked_pacing_ && id - in_flight_ >= first_ && !waitForAcks(id - in_flight_)) continue;  // a restart: see the top
      sendFrame(id);
      ctx_.setLastFrame(id);
      if (replaying) ++resent_;
      else ++sent_;
      ++id;
      reportProgress(id);
    }
  }

  // pacing: live: each frame at its recorded time, never waiting for the
  // consumers, as from a camera: a frame they are not ready for is dropped
  // (the newest wins). Nor does a camera slow down when the computer is busy:
  // when the player is behind its clock (decoding slower than the rate, a
  // starved process) the frames whose time has passed are skipped, never
  // decoded, and the newest one due is sent. A restarted consumer goes on
  // from the next frame.
  void playLive(int64_t from) {
    LiveOutlet outlet(ctx_, *sender_, watch_, consumers_, params_.live_in_flight);
    SourceCountsLog counts(ctx_.outDir());
    int64_t last = -1;
    for (int64_t id = from; id < end_ && !ctx_.stopRequested(); ++id) {
      sleepUntilRecorded(id);
      const int64_t due = newestDue(id);
      outlet.skippedLate(due - id);
      id = due;
      const auto decode_start = Clock::now();
      LoadedFrame loaded = ahead_.take(id);
      const double decode_s = ConsumerWatch::secondsSince(decode_start);
      decode_max_s_ = std::max(decode_max_s_, decode_s);
      counts.frameMade(1e3 * decode_s);
      // Late by the time it goes out (decoding included): as a camera driver's delay.
      const double late_s = std::max(0.0, ConsumerWatch::secondsSince(start_) - scheduledSeconds(id));
      behind_clock_max_s_ = std::max(behind_clock_max_s_, late_s);
      outlet.offer(std::move(loaded.frame), dataset_.intrinsics(), late_s);
      last = id;
      ++sent_;
      reportProgress(id + 1);
      counts.row(id + 1, outlet.counts());
    }
    live_wall_s_ = ConsumerWatch::secondsSince(start_);
    if (last >= 0) behind_clock_end_s_ = live_wall_s_ - scheduledSeconds(last);
    behind_clock_max_s_ = std::max(behind_clock_max_s_, behind_clock_end_s_);
    outlet.finish(params_.wait_timeout_s);
    outlet.writeStats(ctx_.stats());
    const LiveOutlet::Counts c = outlet.counts();
    counts.row(last + 1, c, true);
    spdlog::info("live pacing: {} frames sent, {} dropped (the consumers were not ready), {} skipped (their time had "
                 "passed; the player was up to {:.0f} ms behind its clock)",
                 c.sent, c.dropped, c.skipped_late, 1e3 * behind_clock_max_s_);
    ctx_.stats()
        .set("behind_clock_s_max", behind_clock_max_s_)
        .set("behind_clock_s_end", behind_clock_end_s_)
        .set("decode_s_max", decode_max_s_);
    newest_sent_ = std::max(newest_sent_, c.newest_sent);  // a restarted player's: from before its restart
    eos_.last_frame_id = newest_sent_;
    eos_.frames = played_before_ + c.sent;
    // The recorded time played through, skipped frames included.
    eos_.duration_s = last < first_ ? 0.0
                                    : sequenceSeconds(dataset_, static_cast<size_t>(first_),
                                                      static_cast<size_t>(last - first_ + 1));
    announceEndOfStream(ctx_.bus(), eos_);
  }

  // The newest frame from `id` on whose recorded time has come.
  int64_t newestDue(int64_t id) const {
    const double now_s = ConsumerWatch::secondsSince(start_);
    while (id + 1 < end_ && scheduledSeconds(id + 1) <= now_s) ++id;
    return id;
  }

  void reportProgress(int64_t next) {
    if (ConsumerWatch::secondsSince(last_report_) <= 2.0 && next != end_) return;
    last_report_ = Clock::now();
    // Live, the frames skipped for lateness are played through too.
    const int64_t played = params_.live ? next - first_ : played_before_ + sent_;
    spdlog::info("frame {}/{} ({:.0f} %), {:.1f} frames/s sent", played, count_,
                 100.0 * static_cast<double>(played) / static_cast<double>(count_),
                 static_cast<double>(sent_) / ConsumerWatch::secondsSince(start_));
  }

  // Plays (again) up to the end, lets consumers finish the frames in flight,
  // then announces the end; repeated while a restart rewinds.
  void playToEnd(int64_t from) {
    int64_t next = from;
    while (!ctx_.stopRequested()) {
      play(next, end_);
      if (ctx_.stopRequested()) return;
      if (acked_pacing_ && !waitForAcks(newest_sent_)) {
        next = handleRestarts(end_);
        continue;
      }
      break;
    }
    eos_.last_frame_id = newest_sent_;
    eos_.frames = played_before_ + sent_;
    eos_.duration_s = sequenceSeconds(dataset_, static_cast<size_t>(first_), static_cast<size_t>(eos_.frames));
    announceEndOfStream(ctx_.bus(), eos_);
  }

  // wall_seconds: live, until the last frame went out (the clock's time; the
  // consumers' acknowledgements after it are theirs); else until every frame
  // was acknowledged.
  void reportPlayed() {
    const double wall = params_.live ? live_wall_s_ : ConsumerWatch::secondsSince(start_);
    const char* transport = mode_ == TransportMode::kShm ? "shm" : "lcm";
    const int64_t played = played_before_ + sent_;
    spdlog::info("played {} frames in {:.2f} s ({:.1f} frames/s, transport {})", played, wall,
                 static_cast<double>(played) / std::max(wall, 1e-9), transport);
    ctx_.stats()
        .set("frames", static_cast<long long>(played))
        .set("sequence_seconds", eos_.duration_s)
        .set("wall_seconds", wall)
        .set("transport", transport);
  }

  // Stays until the consumers are done: one restarted meanwhile gets its
  // frames again (from the ring, which lives as long as the sender); live,
  // only the end of the stream (a live source does not rewind).
  void linger() {
    if (params_.live) {
      lingerAfterLiveEnd(ctx_, watch_, peers_, consumers_, eos_);
      return;
    }
    ctx_.setState("lingering");
    while (acked_pacing_ && !ctx_.stopRequested() && !peers_.finished(consumers_)) {
      const int64_t restarts = restarts_;
      const int64_t next = handleRestarts(end_);
      // Also when nothing is left to send (a consumer restarted after it had
      // every frame): it still waits for the end of the stream.
      if (next != end_ || restarts_ != restarts) playToEnd(next);
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }

  ServiceContext& ctx_;
  const PlayerParams& params_;
  const TumDataset dataset_;
  const int64_t first_, end_;  // end_: one past the last frame id
  const size_t count_;
  DecodeAhead ahead_;  // after dataset_ and end_
  ConsumerWatch watch_;
  PeerWatch peers_;
  StopThreadsOnExit stop_threads_;  // after `watch_` and `peers_`: their handlers run on the bus thread
  std::vector<std::string> consumers_;  // player.wait_for, less those a restart found finished
  const bool acked_pacing_;
  TransportMode mode_ = TransportMode::kLcm;
  std::optional<FrameSender> sender_;
  int in_flight_ = 1;
  int64_t newest_sent_ = -1, sent_ = 0, resent_ = 0, rewinds_ = 0;
  int64_t played_before_ = 0;  // a restarted player: the frames its killed instance played
  int64_t restarts_ = 0;  // restarted consumers handled
  Clock::time_point start_, last_report_;
  // pacing: live: when the last frame went out, how late the frames went out
  // (the most, the last), and the longest a frame took to load and decode.
  double live_wall_s_ = 0, behind_clock_max_s_ = 0, behind_clock_end_s_ = 0, decode_max_s_ = 0;
  rekon_msgs::end_of_stream_t eos_{};
};

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
  p.decode_threads = config.getInt("player.decode_threads");
  if (p.decode_threads < 0 || p.decode_threads > 16) throw Error("player.decode_threads must lie in [0, 16]");
  const std::string pacing = config.getString("player.pacing");
  if (pacing != "wait" && pacing != "live") throw Error("player.pacing '" + pacing + "' must be \"wait\" or \"live\"");
  p.live = pacing == "live";
  if (p.live && p.rate <= 0) throw Error("player.pacing live needs player.rate set to a multiple of the recorded rate (e.g. 1), not \"max\"");
  p.live_in_flight = config.getInt("transport.live_in_flight");
  if (p.live_in_flight < 1) throw Error("transport.live_in_flight must be 1 or more");
  p.transport_mode = config.getString("transport.mode");
  p.segment = config.getString("transport.segment");
  p.slots = config.getInt("transport.slots");
  p.max_width = config.getInt("transport.max_width");
  p.max_height = config.getInt("transport.max_height");
  p.restarted = config.getBool("player.restarted");
  if (p.transport_mode != "auto") parseTransportMode(p.transport_mode);
  return p;
}

void runPlayer(ServiceContext& ctx, const PlayerParams& params) { Player(ctx, params).run(); }

}  // namespace rekon
