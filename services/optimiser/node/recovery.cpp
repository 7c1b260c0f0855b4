#include "recovery.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <chrono>
#include <thread>

#include "rekon_msgs/replay_request_t.hpp"

namespace rekon::optimiser {
namespace {

using Clock = std::chrono::steady_clock;

// A request unanswered this long is sent again, at most kReplayTries times.
constexpr double kReplayAnswerS = 2.0;
constexpr int kReplayTries = 4;
// How long a starting optimiser listens for the tracker's heartbeat.
constexpr double kTrackerSeenS = 1.5;
// A restarted optimiser numbers its graph updates from the newest version the
// tracker saw plus this, so that consumers (which ignore versions they have
// seen) take them even when the tracker missed the last few updates.
constexpr int64_t kRestartVersionGap = 1000;

Clock::time_point secondsFromNow(double s) {
  return Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
}

}  // namespace

std::optional<rekon_msgs::replay_end_t> ReplayClient::request() {
  rekon_msgs::replay_request_t req{};
  req.service = ctx_.name();
  req.pid = getpid();
  req.request_id = ++request_id_;
  for (int attempt = 0; attempt < kReplayTries && !ctx_.stopRequested(); ++attempt) {
    ctx_.bus().publish(channel::kReplayRequest, req);
    if (auto end = inbox_.waitForReplayEnd(req.request_id, secondsFromNow(kReplayAnswerS))) return end;
  }
  return std::nullopt;
}

void recoverAtStart(ServiceContext& ctx, const PeerWatch& peers, ReplayClient& replays, Inbox& inbox,
                    GraphWorker& worker) {
  const auto wait_until = secondsFromNow(kTrackerSeenS);
  while (!peers.peer(kUpstreamService) && Clock::now() < wait_until && !ctx.stopRequested())
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const auto tracker = peers.peer(kUpstreamService);
  if (!tracker || tracker->instances == 0) return;
  const auto end = replays.request();
  if (!end) return;
  // A version the tracker saw from us (the previous run's graph, published at
  // once with session.continue) does not make this optimiser a restart.
  if (end->graph_version > worker.version()) {
    worker.continueVersionsAfter(end->graph_version + kRestartVersionGap);
    spdlog::warn("the tracker has seen graph version {}: this optimiser is a restart; rebuilding from its replay "
                 "({} keyframes, {} constraints, {} tracked frames)",
                 end->graph_version, end->keyframes, end->constraints, end->tracked_frames);
  }
  // Its done_t may have gone out before we subscribed: the replay says so.
  if (end->done) {
    spdlog::info("the tracker finished before this optimiser started: final optimisation after the replay");
    inbox.setUpstreamDone();
  }
}

void fillWhatWasLost(ServiceContext& ctx, const PeerWatch& peers, ReplayClient& replays, Inbox& inbox,
                     GraphWorker& worker) {
  for (int round = 0; round < kReplayTries && !ctx.stopRequested() && peers.alive(kUpstreamService, PeerWatch::kSilenceS);
       ++round) {
    const auto end = replays.request();
    worker.apply(inbox.takeGraphItems());
    if (!end) break;  // no tracker answers (e.g. it died): optimise what we have
    const size_t frames = inbox.trackedFrameCount();
    if (static_cast<int64_t>(worker.keyframesSeen()) >= end->keyframes &&
        static_cast<int64_t>(worker.constraintsSeen()) >= end->constraints &&
        static_cast<int64_t>(frames) >= end->tracked_frames)
      break;
    spdlog::warn("missing after the stream: {} keyframes, {} constraints, {} tracked frames of the tracker's; "
                 "asking for them again",
                 end->keyframes - static_cast<int64_t>(worker.keyframesSeen()),
                 end->constraints - static_cast<int64_t>(worker.constraintsSeen()),
                 end->tracked_frames - static_cast<int64_t>(frames));
  }
  if (worker.constraintsWaiting() > 0)
    spdlog::error("{} constraints name a keyframe that never arrived; left out", worker.constraintsWaiting());
}

}  // namespace rekon::optimiser
