#pragma once
// The volume's host tier: voxel blocks streamed out of the active pool. They
// stay in memory up to a budget of blocks; beyond it the blocks farthest from
// the streaming centre move to a spill file on disk (fixed-size records of a
// block's voxels, the file unlinked as soon as it is opened, so that it goes
// with the process however that ends) and come back when they are needed.
#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "rekon/mapper/volume/volume_kernels.hpp"

namespace rekon::volume {

struct HostTierStats {
  int64_t in_memory = 0, on_disk = 0;  // blocks now
  int64_t spilled = 0, read_back = 0;  // blocks moved to disk, and taken back from it, in total
};

class HostBlocks {
 public:
  // memory_max_blocks 0: no budget (every block stays in memory).
  HostBlocks(double voxel_size, int64_t memory_max_blocks, std::string spill_dir);
  ~HostBlocks();
  HostBlocks(const HostBlocks&) = delete;
  HostBlocks& operator=(const HostBlocks&) = delete;

  void insert(const BlockCoord& coord, const Voxel* voxels);
  bool contains(const BlockCoord& coord) const { return blocks_.count(coord) > 0; }
  // Copies the block's kBlockVoxels voxels to `out` and forgets the block.
  void take(const BlockCoord& coord, Voxel* out);
  // The block's voxels in memory, or nullptr when it is on disk (then read()).
  const Voxel* inMemory(const BlockCoord& coord) const;
  // Copies the block's voxels to `out` wherever it is; false when absent.
  bool read(const BlockCoord& coord, Voxel* out) const;
  // Blocks whose centre lies within r of centre (visits only the cells the sphere overlaps).
  std::vector<BlockCoord> within(const Eigen::Vector3d& centre, double r) const;
  std::vector<BlockCoord> coords() const;
  int64_t size() const { return static_cast<int64_t>(blocks_.size()); }
  // Over the budget: the blocks farthest from centre go to disk until 90 % of
  // it is left in memory (so that spilling comes in batches).
  void spillBeyondBudget(const Eigen::Vector3d& centre);
  HostTierStats stats() const;

 private:
  struct CoordHash {
    size_t operator()(const BlockCoord& c) const { return hashBlock(c); }
  };
  struct Entry {
    std::vector<Voxel> voxels;  // empty when on disk
    int64_t record = -1;        // its record in the spill file, or -1
  };
  static BlockCoord cellOf(const BlockCoord& c);
  void writeRecord(int64_t record, const Voxel* voxels);
  void readRecord(int64_t record, Voxel* out) const;
  void openSpillFile();
  [[noreturn]] void fail(const std::string& what) const;

  double voxel_size_;
  int64_t memory_max_blocks_;
  std::string spill_dir_;
  std::unordered_map<BlockCoord, Entry, CoordHash> blocks_;
  // Blocks by coarse cell (kCellBlocks^3 blocks), so that within() visits only
  // the cells a sphere overlaps, not every block.
  static constexpr int kCellBlocks = 8;
  std::unordered_map<BlockCoord, std::vector<BlockCoord>, CoordHash> cells_;
  int fd_ = -1;
  std::string spill_path_;  // for messages: the file is unlinked
  std::vector<int64_t> free_records_;
  int64_t next_record_ = 0;
  int64_t in_memory_ = 0;
  int64_t spilled_ = 0;
  int64_t read_back_ = 0;
};

// A block's centre in metres (voxels sit at integer multiples of voxel_size).
Eigen::Vector3d blockCentre(const BlockCoord& c, double voxel_size);

}  // namespace rekon::volume
