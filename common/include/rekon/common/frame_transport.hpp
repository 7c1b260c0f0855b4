#pragma once
// Frames over the bus: the frame source announces each frame with a frame_t
// message whose images are either in the shared-memory frame ring (transport
// shm) or inline (transport lcm: depth PNG and color bytes exactly as read
// from disk, so every reader decodes bit-identical images).
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon/common/camera.hpp"
#include "rekon/common/frame_ring.hpp"
#include "rekon/common/rgbd_frame.hpp"
#include "rekon_msgs/frame_t.hpp"

namespace rekon {

enum class TransportMode { kShm, kLcm };
TransportMode parseTransportMode(const std::string& text);  // "shm" | "lcm"

class FrameSender {
 public:
  // For kShm, creates the ring `segment` with `layout`.
  FrameSender(Bus& bus, TransportMode mode, const std::string& segment, const FrameRingLayout& layout);
  // Publishes one frame. `encoded` carries the files' bytes for inline
  // transport; when null, lossless PNGs are encoded here.
  void send(const RgbdFrame& frame, const Intrinsics& k, const EncodedFrame* encoded = nullptr);
  TransportMode mode() const { return mode_; }
  int slots() const { return layout_.slots; }

 private:
  Bus& bus_;
  TransportMode mode_;
  FrameRingLayout layout_;
  std::unique_ptr<FrameRingWriter> ring_;
};

class FrameReceiver {
 public:
  // The frame of a frame_t message, or nullopt (with a logged warning naming
  // the reason) when it is malformed, its slot was overwritten or torn, or its
  // images do not decode or do not match the announced size.
  std::optional<RgbdFrame> receive(const rekon_msgs::frame_t& msg, Intrinsics* intrinsics);

  uint64_t dropped() const { return dropped_; }

 private:
  bool reopenIfRecreated(std::unique_ptr<FrameRingReader>& ring);
  std::map<std::string, std::unique_ptr<FrameRingReader>> rings_;
  uint64_t dropped_ = 0;
};

}  // namespace rekon
