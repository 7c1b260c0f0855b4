// The per-frame path allocates nothing once warm: this binary interposes
// glibc's malloc family with counting wrappers, which sees operator new,
// Eigen's aligned buffers and OpenCV's alike (and is why it is its own test
// executable).
#include <gtest/gtest.h>

#include <atomic>
#include <cstddef>

#include "rekon/tracker/tracker.hpp"
#include "synthetic_views.hpp"

namespace {
std::atomic<long> g_allocations{0};
}

extern "C" {
void* __libc_malloc(size_t size);
void* __libc_calloc(size_t n, size_t size);
void* __libc_realloc(void* p, size_t size);
void* __libc_memalign(size_t alignment, size_t size);

void* malloc(size_t size) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_malloc(size);
}
void* calloc(size_t n, size_t size) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_calloc(n, size);
}
void* realloc(void* p, size_t size) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_realloc(p, size);
}
int posix_memalign(void** out, size_t alignment, size_t size) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  *out = __libc_memalign(alignment, size);
  return *out ? 0 : 12;  // ENOMEM
}
void* aligned_alloc(size_t alignment, size_t size) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_memalign(alignment, size);
}
}

namespace rekon::tracker {
namespace {

TEST(TrackerAllocations, TrackingAFrameThatStartsNoKeyframeAllocatesNothing) {
  test::RoomViews room;
  const Trajectory truth = room.trajectory(8);
  std::vector<RgbdFrame> frames;
  for (int i = 0; i < 8; ++i) frames.push_back(room.render(truth[i].pose, synth::Noise::Kinect, i));
  Tracker tracker;
  // Warm-up: the first keyframe and the first alignment size the buffers.
  const long at_start = g_allocations.load();
  for (int i = 0; i < 3; ++i) ASSERT_EQ(tracker.track(frames[i], room.intrinsics()).state, TrackingState::Ok);
  ASSERT_GT(g_allocations.load(), at_start) << "the counting malloc is not in effect; the test would prove nothing";
  for (int i = 3; i < 8; ++i) {
    const long before = g_allocations.load();
    const TrackResult r = tracker.track(frames[i], room.intrinsics());
    const long allocated = g_allocations.load() - before;
    ASSERT_EQ(r.state, TrackingState::Ok);
    if (!r.new_keyframe) {
      EXPECT_EQ(allocated, 0) << "frame " << i;  // a new keyframe copies its images
    }
  }
}

}  // namespace
}  // namespace rekon::tracker
