#include "rekon/common/frame_transport.hpp"

#include <spdlog/spdlog.h>

#include "rekon/common/error.hpp"
#include "rekon/common/image_io.hpp"
#include "rekon/common/messages.hpp"

namespace rekon {

TransportMode parseTransportMode(const std::string& text) {
  if (text == "shm") return TransportMode::kShm;
  if (text == "lcm") return TransportMode::kLcm;
  throw Error("transport mode '" + text + "' is unknown; use shm, lcm or auto");
}

FrameSender::FrameSender(Bus& bus, TransportMode mode, const std::string& segment, const FrameRingLayout& layout)
    : bus_(bus), mode_(mode), layout_(layout) {
  if (mode_ == TransportMode::kShm) ring_ = std::make_unique<FrameRingWriter>(segment, layout);
}

void FrameSender::send(const RgbdFrame& frame, const Intrinsics& k, const EncodedFrame* encoded) {
  rekon_msgs::frame_t msg{};
  msg.frame_id = frame.id;
  msg.timestamp = frame.timestamp;
  setIntrinsics(k, &msg);
  msg.shm_slot = -1;
  msg.depth_png_size = 0;
  msg.color_size = 0;
  if (mode_ == TransportMode::kShm) {
    msg.shm_slot = static_cast<int32_t>(frame.id % ring_->slots());
    msg.shm_generation = static_cast<int64_t>(ring_->write(msg.shm_slot, frame));
    msg.shm_segment = ring_->name();
  } else {
    EncodedFrame local;
    if (!encoded) {
      local = {encodePng(frame.depth), encodePng(frame.color), "png"};
      encoded = &local;
    }
    msg.depth_png.assign(encoded->depth_png.begin(), encoded->depth_png.end());
    msg.depth_png_size = static_cast<int32_t>(msg.depth_png.size());
    msg.color.assign(encoded->color.begin(), encoded->color.end());
    msg.color_size = static_cast<int32_t>(msg.color.size());
    msg.color_format = encoded->color_format;
  }
  bus_.publish(channel::kFrames, msg);
}

// A slot whose generation is not there: either the reader is too slow, or the
// frame source restarted and created the segment again under the same name,
// while `ring` still maps the old one (unlinked, it stays readable to us).
bool FrameReceiver::reopenIfRecreated(std::unique_ptr<FrameRingReader>& ring) {
  std::unique_ptr<FrameRingReader> current;
  try {
    current = std::make_unique<FrameRingReader>(ring->name());
  } catch (const Error&) {
    return false;  // gone for now: the old mapping is all there is
  }
  if (current->sameInstanceAs(*ring)) return false;
  spdlog::info("frame ring '{}' was created again (its frame source restarted): reading the new one", ring->name());
  ring = std::move(current);
  return true;
}

std::optional<RgbdFrame> FrameReceiver::receive(const rekon_msgs::frame_t& msg, Intrinsics* intrinsics) {
  const std::string what = "frame " + std::to_string(msg.frame_id);
  try {
    const Intrinsics k = intrinsicsOf(msg);
    RgbdFrame frame;
    if (!msg.shm_segment.empty()) {
      auto& ring = rings_[msg.shm_segment];
      if (!ring) ring = std::make_unique<FrameRingReader>(msg.shm_segment);
      auto status = ring->read(msg.shm_slot, static_cast<uint64_t>(msg.shm_generation), &frame);
      if (status == FrameRingReader::Status::kOverwritten && reopenIfRecreated(ring))
        status = ring->read(msg.shm_slot, static_cast<uint64_t>(msg.shm_generation), &frame);
      if (status != FrameRingReader::Status::kOk) {
        ++dropped_;
        spdlog::warn("{} dropped: {} (segment {}, slot {})", what, toString(status), msg.shm_segment, msg.shm_slot);
        return std::nullopt;
      }
      if (frame.id != msg.frame_id || frame.depth.cols != k.width || frame.depth.rows != k.height) {
        ++dropped_;
        spdlog::warn("{} dropped: its ring slot holds frame {} of {}x{}", what, frame.id, frame.depth.cols, frame.depth.rows);
        return std::nullopt;
      }
    } else {
      frame.id = msg.frame_id;
      frame.timestamp = msg.timestamp;
      frame.depth = decodeDepthPng(msg.depth_png.data(), msg.depth_png.size(), k.width, k.height, what + " depth");
      frame.color = decodeColor(msg.color.data(), msg.color.size(), k.width, k.height, what + " color");
    }
    if (intrinsics) *intrinsics = k;
    return frame;
  } catch (const Error& e) {
    ++dropped_;
    spdlog::warn("{} dropped: {}", what, e.what());
    return std::nullopt;
  }
}

}  // namespace rekon
