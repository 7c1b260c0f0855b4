// PeerWatch, what every service knows of the others from their heartbeats and
// done_t messages (common/service.hpp), over a real bus in a private network
// namespace: two Bus instances in this process, one sending, one watching.
#include <gtest/gtest.h>

#include <chrono>
#include <string>

#include "rekon/common/bus.hpp"
#include "rekon/common/service.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
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
  EXPECT_FALSE(peers.alive("tracker", PeerWatch::kSilenceS));
  EXPECT_TRUE(peers.finished({"tracker"}, PeerWatch::kSilenceS));  // done

  // "starting" makes it alive but no instance yet (it has not subscribed).
  sender.publish(channel::kHeartbeat, heartbeat("tracker", 4242, "starting"));
  ASSERT_TRUE(dispatchUntil(watched, heartbeats, 0));
  ASSERT_TRUE(peers.peer("tracker").has_value());
  EXPECT_EQ(peers.peer("tracker")->instances, 0);
  EXPECT_TRUE(peers.alive("tracker", PeerWatch::kSilenceS));

  sender.publish(channel::kHeartbeat, heartbeat("tracker", 4242, "running"));
  ASSERT_TRUE(dispatchUntil(watched, heartbeats, 1));
  EXPECT_EQ(peers.peer("tracker")->instances, 1);
  EXPECT_EQ(peers.peer("tracker")->pid, 4242);
  // A new instance is not done, whatever the one before it said.
  EXPECT_FALSE(peers.peer("tracker")->done);
  EXPECT_FALSE(peers.finished({"tracker"}, PeerWatch::kSilenceS));
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
