#pragma once
// What a frame source (the player, a camera) hears from its consumers over
// the bus: who is alive where (and under which pid: a new one is a restart),
// how far each has acknowledged, and where a restarted one wants its frames
// to resume.
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon/common/service.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/resume_point_t.hpp"

namespace rekon {

class ConsumerWatch {
 public:
  using Clock = std::chrono::steady_clock;
  static double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
  enum class Wait { kAcked, kRestarted, kStalled, kStopped };

  explicit ConsumerWatch(Bus& bus) {
    bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [this](const rekon_msgs::heartbeat_t& hb) {
      // A service counts once it has subscribed to its inputs ("running");
      // frames sent while it is still "starting" would be lost to it.
      std::lock_guard<std::mutex> lock(mutex_);
      if (hb.state == "starting") {
        // A new instance of a consumer seen before: the one we knew is dead.
        if (hosts_.count(hb.service) && incarnations_.current(hb.service) != hb.pid) restarting_.insert(hb.service);
        return;
      }
      restarting_.erase(hb.service);
      const bool seen_before = hosts_.count(hb.service) > 0;
      const Incarnations::Seen seen = incarnations_.note(hb.service, hb.pid);
      if (seen == Incarnations::Seen::kSuperseded) return;  // a killed instance's late heartbeat
      if (seen == Incarnations::Seen::kNew && seen_before) restarted_.insert(hb.service);
      hosts_[hb.service] = hb.host;
      heard_[hb.service] = Clock::now();
      last_frames_[hb.service] = hb.last_frame_id;
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
  // consumer restarted (with `or_restarting`: also one of `names` whose new
  // instance is still starting), or no acknowledgement came for `stall_s`.
  Wait waitForAck(const std::vector<std::string>& names, int64_t frame_id, double stall_s, const ServiceContext& ctx,
                  bool or_restarting = false) {
    std::unique_lock<std::mutex> lock(mutex_);
    const auto start = Clock::now();
    const auto restarting = [&] {
      return or_restarting &&
             std::any_of(names.begin(), names.end(), [&](const std::string& n) { return restarting_.count(n) > 0; });
    };
    while (!ctx.stopRequested()) {
      if (!restarted_.empty() || restarting()) return Wait::kRestarted;
      if (minAcked(names) >= frame_id) return Wait::kAcked;
      if (secondsSince(std::max(start, last_ack_)) > stall_s) return Wait::kStalled;
      changed_.wait_for(lock, std::chrono::milliseconds(50));
    }
    return Wait::kStopped;
  }

  // Those of `names` not known to be gone: left out are a consumer whose new
  // instance says "starting" (rekon run restarts a killed one at once), until
  // that one is running, and one heard before but silent for `within_s`.
  std::vector<std::string> present(const std::vector<std::string>& names, double within_s) {
    std::lock_guard<std::mutex> lock(mutex_);
    std::vector<std::string> out;
    for (const auto& n : names) {
      const auto it = heard_.find(n);
      const bool silent = it != heard_.end() && secondsSince(it->second) > within_s;
      if (!silent && !restarting_.count(n)) out.push_back(n);
    }
    return out;
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
      auto it = resume_points_.find({service, incarnations_.current(service)});
      if (it != resume_points_.end()) return it->second;
      if (Clock::now() > deadline) break;
      changed_.wait_for(lock, std::chrono::milliseconds(50));
    }
    return std::nullopt;
  }
  // The newest frame `name` said it has (its heartbeat's last_frame_id; -1
  // before any): where a restarted frame source finds its consumers.
  int64_t lastFrame(const std::string& name) {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = last_frames_.find(name);
    return it == last_frames_.end() ? -1 : it->second;
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
  std::map<std::string, Clock::time_point> heard_;  // each service's last heartbeat past "starting"
  Incarnations incarnations_;  // of the services seen past "starting"
  std::map<std::string, int64_t> acked_;
  std::map<std::string, int64_t> last_frames_;  // from heartbeats
  std::set<std::string> restarted_;
  std::set<std::string> restarting_;  // a new instance said "starting"; the one we knew is dead
  std::map<std::pair<std::string, int>, int64_t> resume_points_;  // (service, pid) -> first missing frame
  Clock::time_point last_ack_ = Clock::now();
};

}  // namespace rekon
