#include "spill_file.hpp"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"

namespace rekon::store {
namespace {

constexpr char kSpillMagic[8] = {'R', 'K', 'S', 'P', 'I', 'L', 'L', '1'};
constexpr uint32_t kSpillVersion = 1;

struct SpillHeader {
  char magic[8];
  uint32_t version;
  int32_t width, height;
  uint32_t reserved;
  int64_t id;
  uint64_t payload_bytes;
  uint64_t checksum;
};
static_assert(sizeof(SpillHeader) == 48, "the on-disk header has no padding");

// The format's checksum starts FNV-1a from 1469598103934665603, the offset
// basis with its last digit missing since version 1; kept so that existing
// spill files and sessions stay readable.
constexpr uint64_t kChecksumSeed = 1469598103934665603ull;


std::string reason() { return std::strerror(errno); }

}  // namespace

size_t keyframeImageBytes(int width, int height) { return static_cast<size_t>(width) * height * (4 + 4 + 3); }

void packKeyframeImages(const fusion::FusedKeyframe& kf, uint8_t* out) {
  const int w = kf.depth.cols, h = kf.depth.rows;
  const size_t pixels = static_cast<size_t>(w) * h;
  kf.depth.copyTo(cv::Mat(h, w, CV_32F, out));
  kf.weight.copyTo(cv::Mat(h, w, CV_32F, out + 4 * pixels));
  kf.color.copyTo(cv::Mat(h, w, CV_8UC3, out + 8 * pixels));
}

void unpackKeyframeImages(const uint8_t* data, int width, int height, fusion::FusedKeyframe& kf) {
  const size_t pixels = static_cast<size_t>(width) * height;
  uint8_t* bytes = const_cast<uint8_t*>(data);  // cv::Mat wants non-const; only cloned from
  kf.depth = cv::Mat(height, width, CV_32F, bytes).clone();
  kf.weight = cv::Mat(height, width, CV_32F, bytes + 4 * pixels).clone();
  kf.color = cv::Mat(height, width, CV_8UC3, bytes + 8 * pixels).clone();
}

std::string spillFilePath(const std::string& dir, const std::string& segment, int64_t id) {
  return (std::filesystem::path(dir) / (segment + "_kf_" + std::to_string(id) + ".rks")).string();
}

bool isSpillFileOf(const std::string& name, const std::string& segment) {
  const std::string prefix = segment + "_kf_";
  if (name.compare(0, prefix.size(), prefix) != 0) return false;
  const auto ends = [&](const std::string& suffix) {
    return name.size() > prefix.size() + suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0;
  };
  return ends(".rks") || ends(".rks.tmp");
}

size_t spillFileBytes(size_t payload_bytes) { return sizeof(SpillHeader) + payload_bytes; }

void writeSpillFile(const std::string& path, int64_t id, int width, int height, const uint8_t* payload, size_t bytes) {
  SpillHeader h{};
  std::memcpy(h.magic, kSpillMagic, sizeof(h.magic));
  h.version = kSpillVersion;
  h.width = width;
  h.height = height;
  h.id = id;
  h.payload_bytes = bytes;
  h.checksum = fnv1a64(payload, bytes, kChecksumSeed);
  const std::string tmp = path + ".tmp";
  const auto fail = [&](const std::string& what) {
    const std::string why = reason();
    std::remove(tmp.c_str());
    throw Error("cannot write keyframe spill file " + path + " (" + what + ": " + why +
                "); free disk space, set mapper.store_spill_dir to a folder with room, or raise mapper.store_mb");
  };
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (f == nullptr) fail("open");
  errno = 0;
  if (std::fwrite(&h, sizeof(h), 1, f) != 1 || std::fwrite(payload, 1, bytes, f) != bytes || std::fflush(f) != 0) {
    const int e = errno;
    std::fclose(f);
    errno = e;
    fail("write");
  }
  if (std::fclose(f) != 0) fail("close");
  if (std::rename(tmp.c_str(), path.c_str()) != 0) fail("rename");
}

void readSpillFile(const std::string& path, int64_t id, int width, int height, uint8_t* payload, size_t bytes,
                   const std::string& fix) {
  const std::string lost = "; keyframe " + std::to_string(id) + " is lost (" + fix + ")";
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (f == nullptr)
    throw Error("keyframe spill file " + path + " cannot be opened (" + reason() + ")" + lost);
  SpillHeader h{};
  const size_t got_header = std::fread(&h, 1, sizeof(h), f);
  const size_t got = got_header == sizeof(h) ? std::fread(payload, 1, bytes, f) : 0;
  const bool longer = got == bytes && std::fgetc(f) != EOF;
  std::fclose(f);
  if (got_header == sizeof(h) && std::memcmp(h.magic, kSpillMagic, sizeof(h.magic)) != 0)
    throw Error("keyframe spill file " + path + " is not a rekon spill file (bad magic)" + lost);
  if (got_header < sizeof(h) || got < bytes)
    throw Error("keyframe spill file " + path + " is truncated (" + std::to_string(got_header + got) + " of " +
                std::to_string(spillFileBytes(bytes)) + " bytes)" + lost);
  if (h.version != kSpillVersion || h.id != id || h.width != width || h.height != height || h.payload_bytes != bytes)
    throw Error("keyframe spill file " + path + " holds another keyframe or format (id " + std::to_string(h.id) + ", " +
                std::to_string(h.width) + "x" + std::to_string(h.height) + ", version " + std::to_string(h.version) + ")" + lost);
  if (longer) throw Error("keyframe spill file " + path + " is longer than " + std::to_string(spillFileBytes(bytes)) + " bytes" + lost);
  if (fnv1a64(payload, bytes, kChecksumSeed) != h.checksum)
    throw Error("keyframe spill file " + path + " is corrupt (checksum mismatch)" + lost);
}

}  // namespace rekon::store
