#include "rekon/common/frame_ring.hpp"

#include <signal.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <boost/interprocess/mapped_region.hpp>
#include <boost/interprocess/shared_memory_object.hpp>
#include <cstring>
#include <fstream>
#include <sstream>

#include "rekon/common/error.hpp"

namespace rekon {
namespace bip = boost::interprocess;
namespace {

constexpr uint64_t kMagic = 0x31524652454b4552ull;  // "REKERFR1"
constexpr uint32_t kLayoutVersion = 1;
constexpr size_t kAlign = 64;

struct RingHeader {
  uint64_t magic;
  uint32_t layout_version;
  int32_t creator_pid;
  uint64_t creator_start_ticks;
  int32_t slots;
  int32_t max_width;
  int32_t max_height;
  int32_t reserved;
  uint64_t slot_bytes;
};

struct SlotHeader {
  std::atomic<uint64_t> sequence;
  int64_t frame_id;
  double timestamp;
  int32_t width;
  int32_t height;
};
static_assert(std::atomic<uint64_t>::is_always_lock_free, "the seqlock needs lock-free 64-bit atomics in shared memory");

constexpr size_t alignUp(size_t n) { return (n + kAlign - 1) / kAlign * kAlign; }
constexpr size_t kHeaderBytes = alignUp(sizeof(RingHeader));
constexpr size_t kSlotHeaderBytes = alignUp(sizeof(SlotHeader));

size_t slotBytes(int w, int h) { return kSlotHeaderBytes + alignUp(static_cast<size_t>(w) * h * 5); }

// Start time of a process in clock ticks since boot (field 22 of /proc/PID/stat),
// so a recycled pid is not mistaken for the segment's creator.
uint64_t processStartTicks(int pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string s;
  if (!std::getline(in, s)) return 0;
  const auto close = s.rfind(')');
  if (close == std::string::npos) return 0;
  std::istringstream ss(s.substr(close + 2));
  std::string field;
  for (int i = 3; i <= 22 && ss >> field; ++i) {
    if (i == 22) return std::stoull(field);
  }
  return 0;
}

bool creatorAlive(const RingHeader& h) {
  if (h.creator_pid <= 0 || kill(h.creator_pid, 0) != 0) return false;
  return processStartTicks(h.creator_pid) == h.creator_start_ticks;
}

SlotHeader* slotAt(void* base, size_t slot_bytes, int slot) {
  return reinterpret_cast<SlotHeader*>(static_cast<char*>(base) + kHeaderBytes + slot_bytes * static_cast<size_t>(slot));
}

std::string sizeText(int w, int h) { return std::to_string(w) + "x" + std::to_string(h); }

// A frame the slot cannot hold (a 1280x720 camera mode or dataset): one line
// with both sizes and the keys that size the slot.
void checkFitsSlot(const RingHeader& h, const RgbdFrame& frame) {
  const int w = frame.depth.cols, ht = frame.depth.rows;
  if (w > h.max_width || ht > h.max_height) {
    throw Error("frame " + std::to_string(frame.id) + " is " + sizeText(w, ht) + ", larger than a frame-ring slot (" +
                sizeText(h.max_width, h.max_height) + "); set transport.max_width to at least " + std::to_string(w) +
                " and transport.max_height to at least " + std::to_string(ht));
  }
  if (frame.depth.type() != CV_16UC1 || frame.color.type() != CV_8UC3 || frame.color.size() != frame.depth.size() ||
      !frame.depth.isContinuous() || !frame.color.isContinuous()) {
    throw Error("frame " + std::to_string(frame.id) +
                " is not 16-bit depth and 8-bit BGR colour of one size in continuous memory (a frame source bug)");
  }
}

}  // namespace

struct FrameRingWriter::Impl {
  bip::shared_memory_object shm;
  bip::mapped_region region;
  RingHeader* header = nullptr;
};

FrameRingWriter::FrameRingWriter(const std::string& name, const FrameRingLayout& layout)
    : impl_(std::make_unique<Impl>()), name_(name) {
  if (layout.slots < 2 || layout.slots > 1024) throw Error("transport.slots = " + std::to_string(layout.slots) + " must be between 2 and 1024");
  if (layout.max_width <= 0 || layout.max_height <= 0 || layout.max_width > 8192 || layout.max_height > 8192) {
    throw Error("transport.max_width/max_height must be between 1 and 8192");
  }
  // A segment of the same name: reuse is never safe, but a crashed run's is stale.
  try {
    bip::shared_memory_object old(bip::open_only, name.c_str(), bip::read_only);
    bip::offset_t size = 0;
    old.get_size(size);
    bool live = false;
    int pid = 0;
    if (static_cast<size_t>(size) >= sizeof(RingHeader)) {
      bip::mapped_region r(old, bip::read_only, 0, sizeof(RingHeader));
      const auto* h = static_cast<const RingHeader*>(r.get_address());
      pid = h->creator_pid;
      live = h->magic == kMagic && creatorAlive(*h);
    }
    if (live) {
      throw Error("shared-memory segment '" + name + "' is in use by a running rekon (pid " + std::to_string(pid) +
                  "); stop it or choose another transport.segment");
    }
    spdlog::warn("removing stale shared-memory segment '{}' left by a crashed run (pid {})", name, pid);
    bip::shared_memory_object::remove(name.c_str());
  } catch (const bip::interprocess_exception&) {
    // No such segment: the normal case.
  }

  const size_t slot_bytes = slotBytes(layout.max_width, layout.max_height);
  const size_t total = kHeaderBytes + slot_bytes * static_cast<size_t>(layout.slots);
  try {
    impl_->shm = bip::shared_memory_object(bip::create_only, name.c_str(), bip::read_write);
    impl_->shm.truncate(static_cast<bip::offset_t>(total));
    impl_->region = bip::mapped_region(impl_->shm, bip::read_write);
  } catch (const bip::interprocess_exception& e) {
    bip::shared_memory_object::remove(name.c_str());
    throw Error("cannot create shared-memory segment '" + name + "' of " + std::to_string(total >> 20) + " MiB (" + e.what() +
                "); free /dev/shm or lower transport.slots");
  }
  void* base = impl_->region.get_address();
  std::memset(base, 0, total);
  auto* h = static_cast<RingHeader*>(base);
  h->layout_version = kLayoutVersion;
  h->creator_pid = getpid();
  h->creator_start_ticks = processStartTicks(getpid());
  h->slots = layout.slots;
  h->max_width = layout.max_width;
  h->max_height = layout.max_height;
  h->slot_bytes = slot_bytes;
  // Generations start at this instance's own even base (its creation time in
  // ns): a receiver still mapping a previous instance of the same name (the
  // frame source restarted) never finds a new frame's generation there, and
  // reopens the segment (FrameReceiver).
  const auto created_ns = std::chrono::system_clock::now().time_since_epoch();
  const uint64_t first_sequence =
      static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(created_ns).count()) & ~uint64_t{1};
  for (int i = 0; i < layout.slots; ++i)
    new (&slotAt(base, slot_bytes, i)->sequence) std::atomic<uint64_t>(first_sequence);
  std::atomic_thread_fence(std::memory_order_release);
  h->magic = kMagic;  // last: a reader never sees a half-initialised header as valid
  impl_->header = h;
}

FrameRingWriter::~FrameRingWriter() { bip::shared_memory_object::remove(name_.c_str()); }

int FrameRingWriter::slots() const { return impl_->header->slots; }

uint64_t FrameRingWriter::write(int slot, const RgbdFrame& frame) {
  const RingHeader& h = *impl_->header;
  if (slot < 0 || slot >= h.slots) throw Error("frame ring slot " + std::to_string(slot) + " out of range");
  checkFitsSlot(h, frame);
  SlotHeader* s = slotAt(impl_->region.get_address(), h.slot_bytes, slot);
  const uint64_t seq = s->sequence.load(std::memory_order_relaxed);
  s->sequence.store(seq + 1, std::memory_order_relaxed);  // odd: being written
  std::atomic_thread_fence(std::memory_order_release);
  s->frame_id = frame.id;
  s->timestamp = frame.timestamp;
  s->width = frame.depth.cols;
  s->height = frame.depth.rows;
  char* payload = reinterpret_cast<char*>(s) + kSlotHeaderBytes;
  const size_t depth_bytes = frame.depth.total() * 2;
  std::memcpy(payload, frame.depth.data, depth_bytes);
  std::memcpy(payload + depth_bytes, frame.color.data, frame.color.total() * 3);
  s->sequence.store(seq + 2, std::memory_order_release);  // even: complete
  return seq + 2;
}

struct FrameRingReader::Impl {
  bip::shared_memory_object shm;
  bip::mapped_region region;
  const RingHeader* header = nullptr;
};

FrameRingReader::FrameRingReader(const std::string& name) : impl_(std::make_unique<Impl>()), name_(name) {
  try {
    impl_->shm = bip::shared_memory_object(bip::open_only, name.c_str(), bip::read_only);
    impl_->region = bip::mapped_region(impl_->shm, bip::read_only);
  } catch (const bip::interprocess_exception& e) {
    throw Error("cannot attach to shared-memory segment '" + name + "' (" + e.what() +
                "); is the frame source running on this host? otherwise set transport.mode: lcm");
  }
  if (impl_->region.get_size() < kHeaderBytes) throw Error("shared-memory segment '" + name + "' is too small to be a rekon frame ring");
  const auto* h = static_cast<const RingHeader*>(impl_->region.get_address());
  if (h->magic != kMagic || h->layout_version != kLayoutVersion) {
    throw Error("shared-memory segment '" + name + "' is not a rekon frame ring of layout " + std::to_string(kLayoutVersion) +
                "; run the same rekon version everywhere");
  }
  if (h->slots < 1 || h->slot_bytes != slotBytes(h->max_width, h->max_height) ||
      kHeaderBytes + h->slot_bytes * static_cast<size_t>(h->slots) > impl_->region.get_size()) {
    throw Error("shared-memory segment '" + name + "' has an inconsistent header; remove it (rm /dev/shm/" + name + ")");
  }
  impl_->header = h;
}

FrameRingReader::~FrameRingReader() = default;

bool FrameRingReader::sameInstanceAs(const FrameRingReader& other) const {
  const RingHeader &a = *impl_->header, &b = *other.impl_->header;
  return a.creator_pid == b.creator_pid && a.creator_start_ticks == b.creator_start_ticks;
}

FrameRingReader::Status FrameRingReader::read(int slot, uint64_t generation, RgbdFrame* out,
                                              const std::function<void()>& during_copy) const {
  const RingHeader& h = *impl_->header;
  if (slot < 0 || slot >= h.slots || generation == 0 || generation % 2 != 0) return Status::kBadReference;
  auto* s = slotAt(const_cast<void*>(impl_->region.get_address()), h.slot_bytes, slot);
  if (s->sequence.load(std::memory_order_acquire) != generation) return Status::kOverwritten;
  const int w = s->width, hgt = s->height;
  if (w <= 0 || hgt <= 0 || w > h.max_width || hgt > h.max_height) return Status::kTorn;
  out->id = s->frame_id;
  out->timestamp = s->timestamp;
  out->depth.create(hgt, w, CV_16UC1);
  out->color.create(hgt, w, CV_8UC3);
  const char* payload = reinterpret_cast<const char*>(s) + kSlotHeaderBytes;
  const size_t depth_bytes = static_cast<size_t>(w) * hgt * 2;
  std::memcpy(out->depth.data, payload, depth_bytes);
  std::memcpy(out->color.data, payload + depth_bytes, static_cast<size_t>(w) * hgt * 3);
  if (during_copy) during_copy();
  std::atomic_thread_fence(std::memory_order_acquire);
  if (s->sequence.load(std::memory_order_relaxed) != generation) return Status::kTorn;
  return Status::kOk;
}

const char* toString(FrameRingReader::Status status) {
  switch (status) {
    case FrameRingReader::Status::kOk: return "ok";
    case FrameRingReader::Status::kOverwritten: return "slot already overwritten (reader too slow)";
    case FrameRingReader::Status::kTorn: return "slot overwritten while reading (torn read)";
    case FrameRingReader::Status::kBadReference: return "slot or generation out of range";
  }
  return "unknown";
}

bool removeFrameRing(const std::string& name) { return bip::shared_memory_object::remove(name.c_str()); }

}  // namespace rekon
