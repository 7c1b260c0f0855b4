// PeerWatch, what every service knows of the others from their heartbeats and
// done_t messages (common/service.hpp), over a real bus in a private network
// namespace: two Bus instances in this process, one sending, one watching.
#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/service.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/resume_point_t.hpp"
#include "test_support.hpp"

namespace {

using rekon::Bus;
using rekon::BusOptions;
using rekon::LcmBus;
using rekon::PeerWatch;
namespace channel = rekon::channel;

// Dispatches `bus` until `count` has grown past `before` (at most 5 s).
bool dispatchUntil(Bus& bus, const int& count, int before) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (count <= before && std::chrono::steady_clock::now() < end) bus.handle(20);
  return count > before;
}

rekon_msgs::heartbeat_t heartbeat(const std::string& service, int pid, const std::string& state) {
  rekon_msgs::heartbeat_t hb{};
  hb.service = service;
  hb.pid = pid;
  hb.host = "here";
  hb.state = state;
  return hb;
}

// A restarted optimiser waits for the tracker's heartbeat: a done_t of the
// tracker that comes first must not pass for it (it did, and the optimiser
// then asked the tracker for no replay and lost the trajectory).
TEST(PeerWatch, ADoneAloneIsNoPeerUntilItsHeartbeatComes) {
  if (!rekon::test::insideNetns()) return;
  LcmBus sender(BusOptions{}), watched(BusOptions{});
  PeerWatch peers(watched);
  int dones = 0, heartbeats = 0;
  watched.subscribe<rekon_msgs::done_t>(channel::kDone, [&](const rekon_msgs::done_t&) { ++dones; });
  watched.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t&) { ++heartbeats; });

  rekon_msgs::done_t done{};
  done.service = "tracker";
  done.last_frame_id = 89;
  sender.publish(channel::kDone, done);
  ASSERT_TRUE(dispatchUntil(watched, dones, 0));
  EXPECT_FALSE(peers.peer("tracker").has_value());
  EXPECT_FALSE(peers.alive("tracker"));
  EXPECT_TRUE(peers.finished({"tracker"}));  // done

  // "starting" makes it alive but no instance yet (it has not subscribed).
  sender.publish(channel::kHeartbeat, heartbeat("tracker", 4242, "starting"));
  ASSERT_TRUE(dispatchUntil(watched, heartbeats, 0));
  ASSERT_TRUE(peers.peer("tracker").has_value());
  EXPECT_EQ(peers.peer("tracker")->instances, 0);
  EXPECT_TRUE(peers.alive("tracker"));

  sender.publish(channel::kHeartbeat, heartbeat("tracker", 4242, "running"));
  ASSERT_TRUE(dispatchUntil(watched, heartbeats, 1));
  EXPECT_EQ(peers.peer("tracker")->instances, 1);
  EXPECT_EQ(peers.peer("tracker")->pid, 4242);
  // A new instance is not done, whatever the one before it said.
  EXPECT_FALSE(peers.peer("tracker")->done);
  EXPECT_FALSE(peers.finished({"tracker"}));
}

// A new pid is a restart: counted, and announced to onNewInstance.
TEST(PeerWatch, ANewPidIsANewInstance) {
  if (!rekon::test::insideNetns()) return;
  LcmBus sender(BusOptions{}), watched(BusOptions{});
  PeerWatch peers(watched);
  int heartbeats = 0, restarts = 0, last_instance = 0;
  watched.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t&) { ++heartbeats; });
  peers.onNewInstance([&](const std::string& service, int instance) {
    EXPECT_EQ(service, "mapper");
    ++restarts;
    last_instance = instance;
  });
  sender.publish(channel::kHeartbeat, heartbeat("mapper", 100, "running"));
  ASSERT_TRUE(dispatchUntil(watched, heartbeats, 0));
  sender.publish(channel::kHeartbeat, heartbeat("mapper", 100, "running"));
  ASSERT_TRUE(dispatchUntil(watched, heartbeats, 1));
  EXPECT_EQ(restarts, 0);
  sender.publish(channel::kHeartbeat, heartbeat("mapper", 101, "running"));
  ASSERT_TRUE(dispatchUntil(watched, heartbeats, 2));
  EXPECT_EQ(restarts, 1);
  EXPECT_EQ(last_instance, 2);
  EXPECT_EQ(peers.peer("mapper")->instances, 2);
}

}  // namespace

namespace {

rekon_msgs::done_t doneOf(const std::string& service, int pid) {
  rekon_msgs::done_t d{};
  d.service = service;
  d.pid = pid;
  d.last_frame_id = 89;
  return d;
}

// A watcher and a sender on the bus, with counters to dispatch up to.
struct Watched {
  LcmBus sender{BusOptions{}}, watched{BusOptions{}};
  PeerWatch peers;
  int messages = 0;
  explicit Watched(rekon::LifecycleTimes times = {}) : peers(watched, times) {
    watched.subscribe<rekon_msgs::done_t>(channel::kDone, [&](const rekon_msgs::done_t&) { ++messages; });
    watched.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t&) { ++messages; });
  }
  template <class Msg>
  bool send(const char* channel, const Msg& m) {
    const int before = messages;
    sender.publish(channel, m);
    return dispatchUntil(watched, messages, before);
  }
};

}  // namespace

// Issue 25, finding 1: the optimiser was done and killed while it lingered;
// its restart's first heartbeat ("starting") must supersede that done at
// once (it did only on "running", and a tracker that saw the optimiser
// finished in between stopped serving the replay the restart needed: the hang).
TEST(PeerWatch, ARestartsStartingHeartbeatSupersedesTheDoneOfTheKilledInstance) {
  if (!rekon::test::insideNetns()) return;
  Watched w;
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("optimiser", 100, "running")));
  ASSERT_TRUE(w.send(channel::kDone, doneOf("optimiser", 100)));
  EXPECT_TRUE(w.peers.done("optimiser"));
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("optimiser", 200, "starting")));
  EXPECT_FALSE(w.peers.done("optimiser"));
  EXPECT_FALSE(w.peers.finished({"optimiser"}));
  EXPECT_EQ(w.peers.peer("optimiser")->pid, 200);
}

// A done_t or heartbeat of the killed instance that arrives after its
// successor's first heartbeat (another socket, another order) counts for nothing.
TEST(PeerWatch, LateMessagesOfASupersededInstanceCountForNothing) {
  if (!rekon::test::insideNetns()) return;
  Watched w;
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("optimiser", 100, "running")));
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("optimiser", 200, "starting")));
  ASSERT_TRUE(w.send(channel::kDone, doneOf("optimiser", 100)));
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("optimiser", 100, "lingering")));
  EXPECT_FALSE(w.peers.done("optimiser"));
  EXPECT_EQ(w.peers.peer("optimiser")->pid, 200);
  EXPECT_EQ(w.peers.peer("optimiser")->state, "starting");
  ASSERT_TRUE(w.send(channel::kDone, doneOf("optimiser", 200)));
  EXPECT_TRUE(w.peers.done("optimiser"));
}

// Done is not finished while the instance is alive and has not said it
// exited: if it is killed now, its restart still needs its upstream.
TEST(PeerWatch, ADoneInstanceIsFinishedOnlyOnceItHasExited) {
  if (!rekon::test::insideNetns()) return;
  Watched w;
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("mapper", 300, "running")));
  ASSERT_TRUE(w.send(channel::kDone, doneOf("mapper", 300)));
  EXPECT_TRUE(w.peers.done("mapper"));
  EXPECT_FALSE(w.peers.finished({"mapper"}));
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("mapper", 300, "exited")));
  EXPECT_TRUE(w.peers.finished({"mapper"}));
  // Exited without done (an error): it may be restarted, so only silence finishes it.
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("optimiser", 301, "exited")));
  EXPECT_FALSE(w.peers.finished({"optimiser"}));
}

// A loaded machine spaces heartbeats out: the silence that means "gone"
// grows with the longest gap seen (silence_gaps x), so a slow peer is not
// given up for a dead one. Silence 0.1 s, gaps of 0.5 s: gone only after 3 s.
TEST(PeerWatch, SilenceScalesWithTheLongestGapBetweenHeartbeats) {
  if (!rekon::test::insideNetns()) return;
  rekon::LifecycleTimes times;
  times.silence_s = 0.1;
  times.silence_gaps = 6;
  Watched w(times);
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("tracker", 400, "running")));
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("tracker", 400, "running")));
  std::this_thread::sleep_for(std::chrono::milliseconds(600));
  EXPECT_FALSE(w.peers.gone("tracker"));  // 0.6 s > silence_s, < 6 x 0.5 s
  EXPECT_TRUE(w.peers.alive("tracker"));
  // A peer never spaced out is gone after silence_s.
  ASSERT_TRUE(w.send(channel::kHeartbeat, heartbeat("mapper", 401, "running")));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_TRUE(w.peers.gone("mapper"));
  EXPECT_TRUE(w.peers.finished({"mapper"}));
}

// A new state is on the bus before anything the service publishes after
// setting it: a restarted mapper's "running" reaches the tracker before its
// resume point, hence before the frames the player sends again from it.
// When only the heartbeat thread sent it, under load it came after them: the
// tracker took those frames for repeats to the killed instance, did not
// answer them, and the mapper dropped them (tools/rekon stress, 5 of 20).
// The heartbeat thread is not even started here.
TEST(PeerWatch, ANewStateIsOnTheBusBeforeWhatTheServicePublishesNext) {
  if (!rekon::test::insideNetns()) return;
  LcmBus watched(BusOptions{});
  std::vector<std::string> seen;
  watched.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t& hb) {
    if (hb.service == "mapper") seen.push_back("heartbeat " + hb.state);
  });
  watched.subscribe<rekon_msgs::resume_point_t>(channel::kResumePoint,
                                                [&](const rekon_msgs::resume_point_t&) { seen.push_back("resume point"); });
  rekon::ArgParser args("rekon-mapper", "in-process");
  rekon::ServiceContext ctx("mapper", rekon::Config::load("", {}), "", args);
  ctx.setState("running");
  rekon_msgs::resume_point_t point{};
  point.service = "mapper";
  ctx.bus().publish(channel::kResumePoint, point);
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while ((seen.empty() || seen.back() != "resume point") && std::chrono::steady_clock::now() < end) watched.handle(20);
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_EQ(seen[0], "heartbeat running");
  EXPECT_EQ(seen[1], "resume point");
}

// "exited" is an instance's last word. A service whose body stops its threads
// itself (the tracker, the optimiser, the mapper: no handler may run while
// they write their outputs) said "exited" there, and runInContext's
// "finished" then went out after it: every peer that lingers for it waited
// for its silence instead (7scenes_loop_1000's run ended 9-14 s after its
// last service's outputs, realtime_factor 1.4-1.6 -> 1.0-1.1).
TEST(PeerWatch, AServiceThatStoppedItsThreadsInItsBodyIsFinishedAtOnce) {
  if (!rekon::test::insideNetns()) return;
  LcmBus watched(BusOptions{});
  PeerWatch peers(watched);
  std::vector<std::string> states;
  watched.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t& hb) {
    if (hb.service == "mapper") states.push_back(hb.state);
  });
  rekon::ArgParser args("rekon-mapper", "in-process");
  rekon::ServiceContext ctx("mapper", rekon::Config::load("", {}), "", args);
  const int rc = rekon::runInContext(ctx, [](rekon::ServiceContext& c) {
    c.setState("running");
    c.bus().publish(channel::kDone, rekon::doneMessage("mapper", 9));
    c.stopThreads();
  });
  ASSERT_EQ(rc, 0);
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(2);
  while (std::chrono::steady_clock::now() < end) watched.handle(20);  // everything it sent, and nothing comes after
  ASSERT_FALSE(states.empty());
  EXPECT_EQ(states.back(), "exited");
  EXPECT_TRUE(peers.finished({"mapper"}));  // long before lifecycle.silence_s (5 s)
}
