#include "host_blocks.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>

#include "rekon/common/error.hpp"

namespace rekon::volume {
namespace {

constexpr size_t kRecordBytes = kBlockVoxels * sizeof(Voxel);

}  // namespace

Eigen::Vector3d blockCentre(const BlockCoord& c, double voxel_size) {
  const double side = kBlockSide * voxel_size;
  // A block spans [c*side, (c+1)*side - voxel_size].
  const double half = 0.5 * (side - voxel_size);
  return {c.x * side + half, c.y * side + half, c.z * side + half};
}

HostBlocks::HostBlocks(double voxel_size, int64_t memory_max_blocks, std::string spill_dir)
    : voxel_size_(voxel_size), memory_max_blocks_(memory_max_blocks), spill_dir_(std::move(spill_dir)) {}

HostBlocks::~HostBlocks() {
  if (fd_ >= 0) ::close(fd_);
}

BlockCoord HostBlocks::cellOf(const BlockCoord& c) {
  return {floorDiv(c.x, kCellBlocks), floorDiv(c.y, kCellBlocks), floorDiv(c.z, kCellBlocks)};
}

void HostBlocks::insert(const BlockCoord& coord, const Voxel* voxels) {
  Entry& e = blocks_[coord];
  e.voxels.assign(voxels, voxels + kBlockVoxels);
  e.record = -1;
  ++in_memory_;
  cells_[cellOf(coord)].push_back(coord);
}

void HostBlocks::take(const BlockCoord& coord, Voxel* out) {
  auto it = blocks_.find(coord);
  if (it == blocks_.end()) throw Error("volume: internal error: block taken from the host tier is not there");
  if (it->second.record >= 0) {
    readRecord(it->second.record, out);
    free_records_.push_back(it->second.record);
    ++read_back_;
  } else {
    std::copy(it->second.voxels.begin(), it->second.voxels.end(), out);
    --in_memory_;
  }
  blocks_.erase(it);
  const BlockCoord cell = cellOf(coord);
  auto& members = cells_[cell];
  const auto m = std::find(members.begin(), members.end(), coord);
  *m = members.back();
  members.pop_back();
  if (members.empty()) cells_.erase(cell);
}

const Voxel* HostBlocks::inMemory(const BlockCoord& coord) const {
  const auto it = blocks_.find(coord);
  return it == blocks_.end() || it->second.record >= 0 ? nullptr : it->second.voxels.data();
}

bool HostBlocks::read(const BlockCoord& coord, Voxel* out) const {
  const auto it = blocks_.find(coord);
  if (it == blocks_.end()) return false;
  if (it->second.record >= 0) readRecord(it->second.record, out);
  else std::copy(it->second.voxels.begin(), it->second.voxels.end(), out);
  return true;
}

std::vector<BlockCoord> HostBlocks::within(const Eigen::Vector3d& centre, double r) const {
  std::vector<BlockCoord> out;
  const double cell_side = kCellBlocks * kBlockSide * voxel_size_;
  const Eigen::Vector3i lo = ((centre.array() - r) / cell_side).floor().cast<int>();
  const Eigen::Vector3i hi = ((centre.array() + r) / cell_side).floor().cast<int>();
  for (int z = lo.z(); z <= hi.z(); ++z) {
    for (int y = lo.y(); y <= hi.y(); ++y) {
      for (int x = lo.x(); x <= hi.x(); ++x) {
        const auto cell = cells_.find({x, y, z});
        if (cell == cells_.end()) continue;
        for (const BlockCoord& coord : cell->second)
          if ((blockCentre(coord, voxel_size_) - centre).norm() <= r) out.push_back(coord);
      }
    }
  }
  return out;
}

std::vector<BlockCoord> HostBlocks::coords() const {
  std::vector<BlockCoord> out;
  out.reserve(blocks_.size());
  for (const auto& [coord, entry] : blocks_) out.push_back(coord);
  return out;
}

void HostBlocks::spillBeyondBudget(const Eigen::Vector3d& centre) {
  if (memory_max_blocks_ <= 0 || in_memory_ <= memory_max_blocks_) return;
  std::vector<std::pair<double, Entry*>> resident;
  for (auto& [coord, entry] : blocks_)
    if (entry.record < 0) resident.emplace_back((blockCentre(coord, voxel_size_) - centre).squaredNorm(), &entry);
  const size_t n = static_cast<size_t>(in_memory_ - memory_max_blocks_ * 9 / 10);
  std::nth_element(resident.begin(), resident.begin() + static_cast<std::ptrdiff_t>(n), resident.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  for (size_t i = 0; i < n; ++i) {
    Entry& e = *resident[i].second;
    int64_t record = next_record_;
    if (!free_records_.empty()) {
      record = free_records_.back();
      free_records_.pop_back();
    } else {
      ++next_record_;
    }
    writeRecord(record, e.voxels.data());
    e.record = record;
    std::vector<Voxel>().swap(e.voxels);  // the memory goes back
    --in_memory_;
    ++spilled_;
  }
}

HostTierStats HostBlocks::stats() const {
  return {in_memory_, size() - in_memory_, spilled_, read_back_};
}

void HostBlocks::openSpillFile() {
  static std::atomic<int> serial{0};
  if (spill_dir_.empty())
    throw Error("volume: the host tier is over its budget but has no spill folder; set mapper.voxel_spill_dir "
                "(auto = $TMPDIR or /tmp) or mapper.host_mb 0 (no budget)");
  std::error_code ec;
  std::filesystem::create_directories(spill_dir_, ec);
  spill_path_ = (std::filesystem::path(spill_dir_) /
                 ("rekon_voxels_" + std::to_string(::getpid()) + "_" + std::to_string(serial++) + ".spill"))
                    .string();
  fd_ = ::open(spill_path_.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd_ < 0) fail("open");
  ::unlink(spill_path_.c_str());  // gone with the process, however it ends
}

void HostBlocks::writeRecord(int64_t record, const Voxel* voxels) {
  if (fd_ < 0) openSpillFile();
  const char* p = reinterpret_cast<const char*>(voxels);
  size_t done = 0;
  while (done < kRecordBytes) {
    const ssize_t n = ::pwrite(fd_, p + done, kRecordBytes - done, static_cast<off_t>(record * kRecordBytes + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) fail("write");
    done += static_cast<size_t>(n);
  }
}

void HostBlocks::readRecord(int64_t record, Voxel* out) const {
  char* p = reinterpret_cast<char*>(out);
  size_t done = 0;
  while (done < kRecordBytes) {
    const ssize_t n = ::pread(fd_, p + done, kRecordBytes - done, static_cast<off_t>(record * kRecordBytes + done));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) fail("read");
    if (n == 0) {
      errno = 0;
      fail("read (short file)");
    }
    done += static_cast<size_t>(n);
  }
}

void HostBlocks::fail(const std::string& what) const {
  const std::string why = errno != 0 ? std::strerror(errno) : "no error code";
  throw Error("volume: voxel spill file " + spill_path_ + ": " + what + " failed (" + why +
              "); free disk space, set mapper.voxel_spill_dir to a folder with room, or raise mapper.host_mb");
}

}  // namespace rekon::volume
