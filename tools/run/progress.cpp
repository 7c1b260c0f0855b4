#include "progress.hpp"

#include "rekon_msgs/heartbeat_t.hpp"

#include <algorithm>

namespace rekon {

RunProgress::RunProgress(const Config& config, long long total_frames, long long first_frame_id, double source_fps,
                         Clock::time_point started)
    : bus_(makeBus(BusOptions::fromConfig(config))), total_(total_frames), first_frame_id_(first_frame_id),
      source_fps_(source_fps), started_(started) {
  bus_->subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [this](const rekon_msgs::heartbeat_t& hb) {
    heard_[hb.service] = {hb.pid, hb.state, hb.last_frame_id};
  });
}

long long RunProgress::framesDone() const {
  for (const char* s : {"mapper", "tracker", "player", "camera"}) {  // the furthest downstream that reports
    const auto it = services_.find(s);
    if (it != services_.end() && it->second.second >= 0) return std::max(0LL, it->second.second + 1 - first_frame_id_);
  }
  return 0;
}

std::string RunProgress::text() const {
  double rate = 0;
  if (samples_.size() > 1) {
    const double seconds = std::chrono::duration<double>(samples_.back().first - samples_.front().first).count();
    if (seconds > 0.5) rate = static_cast<double>(samples_.back().second - samples_.front().second) / seconds;
  }
  const long long done = framesDone();
  const double elapsed = std::chrono::duration<double>(Clock::now() - started_).count();
  const double realtime = source_fps_ > 0 && elapsed > 0 ? static_cast<double>(done) / source_fps_ / elapsed : 0.0;
  std::string s = frameProgress(done, total_, rate, realtime);
  std::string others;  // the services not in their working state
  for (const auto& [name, state] : services_) {
    if (state.first != "running" && state.first != "playing" && name != "viewer")
      others += (others.empty() ? "" : ", ") + name + " " + state.first;
  }
  return s + (services_.empty() ? " (services starting)" : others.empty() ? "" : " (" + others + ")");
}

void RunProgress::poll(const std::set<int>& pids) {
  while (bus_->handle(0)) {
  }
  for (const auto& [service, h] : heard_) {
    if (pids.count(h.pid)) services_[service] = {h.state, h.last_frame};
  }
  const auto now = Clock::now();
  const long long done = framesDone();
  if (done > 0 && first_.second == 0) first_ = {now, done};
  if (done != last_.second) last_ = {now, done};
  samples_.emplace_back(now, done);
  while (samples_.size() > 2 && now - samples_.front().first > std::chrono::duration<double>(kRateWindowS)) samples_.pop_front();
  line_.update(text());
}

double RunProgress::overallRate() const {
  const double seconds = std::chrono::duration<double>(last_.first - first_.first).count();
  if (seconds > 0) return static_cast<double>(last_.second - first_.second) / seconds;
  // A run so short that one poll saw it all (20 frames between two
  // heartbeats): its frames over the time since the services started.
  const double since_start = std::chrono::duration<double>(last_.first - started_).count();
  return since_start > 0 ? static_cast<double>(last_.second) / since_start : 0.0;
}

void RunProgress::finish(double realtime_factor, bool interrupted) {
  while (bus_->handle(0)) {
  }
  const long long done = framesDone();
  line_.finish(frameProgress(done, total_, overallRate(), realtime_factor, true) + (interrupted ? " (interrupted)" : ""));
}

}  // namespace rekon
