#pragma once
// The shared-memory frame ring (Boost.Interprocess): a named segment created by
// the frame source holding a fixed number of slots, each one RGB-D frame.
//
// Segment layout (all little-endian, 64-byte aligned):
//   RingHeader { magic, layout_version, creator pid + start time, slot count,
//                max width/height }                        one per segment
//   Slot[i]    { sequence (seqlock), frame id, timestamp, width, height,
//                depth uint16[w*h], color bgr8[w*h*3] }      slot_count times
// A slot's sequence is odd while the writer fills it and even when complete;
// its generation is the sequence after the write. A reader checks the
// generation before and after copying: a change means the slot was
// overwritten under it (a torn read), and the frame is dropped, never used.
// Each instance of a segment starts its generations at its own base, so a
// generation of one instance is never found in another of the same name.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "rekon/common/rgbd_frame.hpp"

namespace rekon {

struct FrameRingLayout {
  int slots = 8;
  int max_width = 640;
  int max_height = 480;
};

class FrameRingWriter {
 public:
  // Creates segment `name`. A segment left by a crashed run (its creator is
  // gone) is removed and recreated with a warning; one owned by a live process
  // is an error naming that process.
  FrameRingWriter(const std::string& name, const FrameRingLayout& layout);
  ~FrameRingWriter();  // removes the segment
  FrameRingWriter(const FrameRingWriter&) = delete;
  FrameRingWriter& operator=(const FrameRingWriter&) = delete;

  // Copies `frame` into `slot`; returns the slot's new generation. Throws
  // rekon::Error naming both sizes and transport.max_width/max_height for a
  // frame larger than a slot.
  uint64_t write(int slot, const RgbdFrame& frame);
  const std::string& name() const { return name_; }
  int slots() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string name_;
};

class FrameRingReader {
 public:
  // Attaches to an existing segment; throws rekon::Error when it is missing or
  // not a rekon frame ring of a known layout.
  explicit FrameRingReader(const std::string& name);
  ~FrameRingReader();

  enum class Status { kOk, kOverwritten, kTorn, kBadReference };
  // Copies slot `slot` into `out` when its generation is `generation` and it
  // did not change while copying. `during_copy` is a test hook run between the
  // copy and the final check.
  Status read(int slot, uint64_t generation, RgbdFrame* out, const std::function<void()>& during_copy = {}) const;
  const std::string& name() const { return name_; }
  // Whether both readers map the segment one writer instance created (a
  // restarted frame source creates the name again).
  bool sameInstanceAs(const FrameRingReader& other) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string name_;
};

const char* toString(FrameRingReader::Status status);
// Removes segment `name` if it exists (launcher clean-up after a crash).
bool removeFrameRing(const std::string& name);

}  // namespace rekon
