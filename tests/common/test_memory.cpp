// releaseFreedMemoryBeyond (common/memory.hpp): the pages of holes between
// live blocks go back to the kernel past the slack, and only then.
#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>
#include <vector>

#include "rekon/common/memory.hpp"
#include "test_support.hpp"


namespace {

constexpr size_t kMiB = size_t{1} << 20;

// Keeps the compiler from dropping an allocation it can see is never read.
void touch(char* p, size_t bytes) {
  std::memset(p, 1, bytes);
  asm volatile("" : : "r"(p) : "memory");
}

TEST(ReleaseFreedMemory, HandsBackHolesBetweenLiveBlocksOnlyPastTheSlack) {
  if (!REKON_GLIBC_HEAP) GTEST_SKIP() << "the sanitizer's allocator replaces glibc's heap, which this test measures";
  rekon::keepFreedMemory();  // as in every service: big blocks come from the heap, nothing is trimmed by itself
  ASSERT_GT(rekon::residentAnonymousBytes(), 0u) << "/proc/self/status has no RssAnon";
  // 32 holes of 2 MiB, each between live small blocks: not at the heap's
  // top, so glibc could only hand them back page by page.
  constexpr size_t kBig = 2 * kMiB, kHoles = 32;
  std::vector<char*> big, small;
  for (size_t i = 0; i < kHoles; ++i) {
    big.push_back(static_cast<char*>(std::malloc(kBig)));
    touch(big.back(), kBig);
    small.push_back(static_cast<char*>(std::malloc(64)));
    touch(small.back(), 64);
  }
  for (char* p : big) std::free(p);
  const size_t held = rekon::residentAnonymousBytes();

  EXPECT_FALSE(rekon::releaseFreedMemoryBeyond(kHoles * kBig + 64 * kMiB));  // within the slack: kept
  EXPECT_GE(rekon::residentAnonymousBytes() + 4 * kMiB, held);
  EXPECT_TRUE(rekon::releaseFreedMemoryBeyond(16 * kMiB));
  const size_t after = rekon::residentAnonymousBytes();
  // The holes are 64 MiB; their first and last page hold malloc's headers
  // and may stay, so at least 56 MiB must go (measured: 64 MiB).
  EXPECT_LE(after + 56 * kMiB, held) << "held " << held / kMiB << " MiB, after the trim " << after / kMiB << " MiB";
  for (char* p : small) std::free(p);
}

}  // namespace
