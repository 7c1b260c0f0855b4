// LcmBus over liblcm's in-process provider (memq://, no socket): a handler's
// exception. Handlers run inside liblcm's C dispatch (lcm_handle); C frames
// promise nothing to C++ unwinding, and liblcm's own state (its in-handle
// flag, its dispatch lock) is left as it was when the exception went through.
// The exception must come out of handle() after liblcm returned, and the bus
// must go on delivering.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon/common/error.hpp"
#include "rekon_msgs/frame_ack_t.hpp"

namespace rekon {
namespace {

rekon_msgs::frame_ack_t ack(int64_t id) {
  rekon_msgs::frame_ack_t a{};
  a.service = "test";
  a.frame_id = id;
  return a;
}

TEST(LcmBus, AHandlersExceptionComesOutOfHandleAndTheBusGoesOn) {
  BusOptions options;
  options.url = "memq://";
  LcmBus bus(options);
  std::vector<int64_t> heard;
  bus.subscribe<rekon_msgs::frame_ack_t>(channel::kFrameAck, [&](const rekon_msgs::frame_ack_t& m) {
    if (m.frame_id == 1) throw Error("the handler of frame 1 failed");
    heard.push_back(m.frame_id);
  });
  bus.publish(channel::kFrameAck, ack(1));
  try {
    bus.handle(1000);
    ADD_FAILURE() << "handle() returned without the handler's exception";
  } catch (const Error& e) {
    EXPECT_STREQ(e.what(), "the handler of frame 1 failed");
  }
  bus.publish(channel::kFrameAck, ack(2));
  EXPECT_TRUE(bus.handle(1000));
  EXPECT_EQ(heard, std::vector<int64_t>{2}) << "the message after the failed one is delivered";
}

}  // namespace
}  // namespace rekon
