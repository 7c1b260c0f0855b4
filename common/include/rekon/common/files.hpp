#pragma once
// Files that must never be seen half-written (a session's files): the bytes
// go to PATH.tmp, which is renamed over PATH, so a reader, or what a killed
// process left, has the old or the new content, never a mix. No fsync: this
// guards against processes that die (kill -9, a crash), not power cuts,
// which would cost the writer a disk flush per file.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

namespace rekon {

// rekon::Error naming the file and the reason (e.g. no space left) when it cannot be written.
void writeFileAtomically(const std::string& path, std::string_view bytes);

// $TMPDIR, else /tmp: where rekon's automatic spill folders go (the
// mapper's keyframe store, the tracker's keyframe cache).
std::string tempFolder();

// FNV-1a 64 of `n` bytes, continuing from `h` (the offset basis to start): the
// checksum of rekon's binary files and the hash of frames.
inline constexpr uint64_t kFnv1aOffset = 14695981039346656037ull;
uint64_t fnv1a64(const void* bytes, size_t n, uint64_t h = kFnv1aOffset);

}  // namespace rekon
