#pragma once
// A frame consumer's acknowledgement (messages/FRONTEND.md FC8): done with
// every frame up to `frame_id`, under this service's name (the one the frame
// source waits for), and the frame its heartbeat reports.
#include <cstdint>

#include "rekon/common/service.hpp"
#include "rekon_msgs/frame_ack_t.hpp"

namespace rekon {

// The acknowledgement alone, for a consumer that moves its heartbeat's frame
// on its own terms (the tracker: only for frames it tracked).
inline void publishFrameAck(ServiceContext& ctx, int64_t frame_id) {
  rekon_msgs::frame_ack_t ack{};
  ack.service = ctx.name();
  ack.frame_id = frame_id;
  ctx.bus().publish(channel::kFrameAck, ack);
}

inline void acknowledgeFrame(ServiceContext& ctx, int64_t frame_id) {
  publishFrameAck(ctx, frame_id);
  ctx.setLastFrame(frame_id);
}

}  // namespace rekon
