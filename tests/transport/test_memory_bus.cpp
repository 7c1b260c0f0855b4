// MemoryBus (memory://NAME): the bus without sockets that unit tests of
// service logic run on. It must behave as LCM multicast does where services
// rely on it: every bus of the name hears every message (its own too), in
// order, decoded and checked like on the wire; other names hear nothing.
#include <gtest/gtest.h>

#include <string>
#include <thread>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon_msgs/frame_ack_t.hpp"

namespace rekon {
namespace {

BusOptions memory(const std::string& name) {
  BusOptions o;
  o.url = "memory://" + name;
  return o;
}

rekon_msgs::frame_ack_t ack(int64_t id) {
  rekon_msgs::frame_ack_t a{};
  a.service = "test";
  a.frame_id = id;
  return a;
}

void drain(Bus& bus) {
  while (bus.handle(0)) {
  }
}

TEST(MemoryBus, EveryBusOfTheNameHearsEveryMessageInOrderItsOwnToo) {
  MemoryBus a(memory("order")), b(memory("order")), other(memory("elsewhere"));
  std::vector<int64_t> heard_a, heard_b, heard_other;
  a.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const auto& m) { heard_a.push_back(m.frame_id); });
  b.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const auto& m) { heard_b.push_back(m.frame_id); });
  other.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const auto& m) { heard_other.push_back(m.frame_id); });
  for (int64_t i = 0; i < 5; ++i) a.publish(channel::kFrameAck, ack(i));
  b.publish(channel::kFrameAck, ack(5));
  drain(a), drain(b), drain(other);
  const std::vector<int64_t> all = {0, 1, 2, 3, 4, 5};
  EXPECT_EQ(heard_a, all);
  EXPECT_EQ(heard_b, all);
  EXPECT_TRUE(heard_other.empty());
}

TEST(MemoryBus, OnlyTheChannelSubscribedToIsDelivered) {
  MemoryBus bus(memory("channels"));
  int acks = 0;
  bus.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const auto&) { ++acks; });
  bus.publish(channel::kHeartbeat, ack(1));  // nobody listens there
  bus.publish(channel::kFrameAck, ack(2));
  drain(bus);
  EXPECT_EQ(acks, 1);
}

TEST(MemoryBus, MalformedBytesAreCountedAndDroppedLikeOnTheWire) {
  MemoryBus bus(memory("malformed"));
  int acks = 0;
  bus.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const auto&) { ++acks; });
  const std::string junk(40, '\x5a');
  bus.publishRaw(channel::kFrameAck, junk.data(), static_cast<int>(junk.size()));
  rekon_msgs::frame_ack_t wrong_version = ack(3);
  wrong_version.schema_version = kSchemaVersion + 1;
  std::string bytes(static_cast<size_t>(wrong_version.getEncodedSize()), '\0');
  wrong_version.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  bus.publishRaw(channel::kFrameAck, bytes.data(), static_cast<int>(bytes.size()));
  drain(bus);
  EXPECT_EQ(acks, 0);
  EXPECT_EQ(bus.malformedCount(), 2u);
}

TEST(MemoryBus, HandleWaitsForAMessageFromAnotherThread) {
  MemoryBus receiver(memory("threads")), sender(memory("threads"));
  int64_t heard = -1;
  receiver.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const auto& m) { heard = m.frame_id; });
  std::thread t([&] { sender.publish(channel::kFrameAck, ack(7)); });
  const bool got = receiver.handle(5000);
  t.join();
  EXPECT_TRUE(got);
  EXPECT_EQ(heard, 7);
  EXPECT_FALSE(receiver.handle(10));  // nothing more
}

TEST(MemoryBus, MakeBusPicksTheImplementationFromTheUrl) {
  EXPECT_NE(dynamic_cast<MemoryBus*>(makeBus(memory("pick")).get()), nullptr);
}

}  // namespace
}  // namespace rekon
