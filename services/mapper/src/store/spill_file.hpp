#pragma once
// One spilled KF keyframe on disk: a fixed header (magic "RKSPILL1", format
// version, keyframe id, image size, payload bytes, FNV-1a 64 checksum of the
// payload), then the payload exactly as it lies in the segment (depth and
// weight as float, color as BGR bytes). Files are written under a temporary
// name and renamed, so a crash never leaves a half-written file under the
// final name.
#include <cstddef>
#include <cstdint>
#include <string>

#include "rekon/mapper/fusion/keyframe_fusion.hpp"

namespace rekon::store {

// A KF keyframe's images as the store, its spill files and session files
// hold them: depth and weight (float, metres and W*) then color (BGR bytes).
size_t keyframeImageBytes(int width, int height);
// `out` holds keyframeImageBytes(width, height) for the keyframe's own size.
void packKeyframeImages(const fusion::FusedKeyframe& kf, uint8_t* out);
// Sets kf.depth, kf.weight and kf.color (copies of `data`).
void unpackKeyframeImages(const uint8_t* data, int width, int height, fusion::FusedKeyframe& kf);

// "<dir>/<segment>_kf_<id>.rks"
std::string spillFilePath(const std::string& dir, const std::string& segment, int64_t id);
// True for the spill files (and leftovers of interrupted writes) of `segment`.
bool isSpillFileOf(const std::string& file_name, const std::string& segment);

// rekon::Error naming the file and errno's reason (e.g. no space left) when it cannot be written.
void writeSpillFile(const std::string& path, int64_t id, int width, int height, const uint8_t* payload, size_t bytes);
// Fills `payload` (exactly `bytes`); rekon::Error when the file is missing,
// truncated, longer than it should be, of another keyframe or size, or fails
// its checksum, ending with `fix` (what the user can do).
inline constexpr const char* kStoreFileFix = "remove the store with rekon keyframes --remove and map again";
void readSpillFile(const std::string& path, int64_t id, int width, int height, uint8_t* payload, size_t bytes,
                   const std::string& fix = kStoreFileFix);

// Header plus payload: the bytes a spill file takes on disk.
size_t spillFileBytes(size_t payload_bytes);

}  // namespace rekon::store
