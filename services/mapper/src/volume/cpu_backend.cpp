// The CPU backend: the shared kernels in loops over a persistent thread pool.
#include <algorithm>
#include <climits>
#include <cstring>
#include <memory>
#include <type_traits>

#include "parallel_for.hpp"
#include "rekon/common/simd.hpp"
#include "rekon/mapper/volume/volume_backend.hpp"

namespace rekon::volume {
namespace {

// Direct-mapped cache of recently emitted blocks per worker: neighbouring
// pixels cross the same blocks, so most duplicates never reach the hash.
constexpr int kRecentBlocks = 1 << 12;
constexpr int kRowsPerChunk = 8;
constexpr int kBlocksPerChunk = 16;

// Updates blocks [begin, end) of one worker's chunk. Built for AVX2 and the
// baseline (REKON_SIMD_CLONES): a block's rows are 8 voxels, one AVX2 vector.
// Returns the UpdateStatus values that occurred, ORed.
REKON_SIMD_CLONES int updateChunk(Voxel* pool, const BlockRef* blocks, int begin, int end, const FrameImages& frame,
                                  const CameraView& cam, const IntegrationSettings& s, int sign, uint8_t* empty) {
  int flags = 0;
  for (int i = begin; i < end; ++i) {
    Voxel* voxels = pool + static_cast<size_t>(blocks[i].slot) * kBlockVoxels;
    const BlockUpdateResult r = updateBlock(voxels, blocks[i].coord, frame, cam, s, sign);
    flags |= (r.overflow ? kWeightOverflow : 0) | (r.underflow ? kWeightUnderflow : 0);
    empty[i] = r.occupied ? 0 : 1;
  }
  return flags;
}

// The voxel pool, not value-initialised: every slot is written when it is
// taken (a fresh block's zeros or its voxels streamed in), so the pages of
// slots never taken are not touched until the pool grows (a growth copies
// the old pool whole). A std::vector zeroed the whole of
// volume.block_capacity at start (192 MiB of page faults and RSS where
// 7-Scenes uses 62 MiB).
class VoxelPool {
  static_assert(std::is_trivial_v<Voxel>, "new Voxel[n] must leave the pool's pages untouched");

 public:
  Voxel* data() { return voxels_.get(); }
  const Voxel* data() const { return voxels_.get(); }
  // Keeps the first min(old, new) voxels.
  void resize(size_t voxels) {
    std::unique_ptr<Voxel[]> grown(new Voxel[voxels]);  // a trivial type: left as the allocator gives it
    if (size_ > 0) std::memcpy(grown.get(), voxels_.get(), sizeof(Voxel) * std::min(size_, voxels));
    voxels_ = std::move(grown);
    size_ = voxels;
  }

 private:
  std::unique_ptr<Voxel[]> voxels_;
  size_t size_ = 0;
};

class CpuBackend final : public VolumeBackend {
 public:
  explicit CpuBackend(int threads) : threads_(threads) {}
  std::string name() const override { return "cpu"; }

  void resizePool(int32_t blocks) override { pool_.resize(static_cast<size_t>(blocks) * kBlockVoxels); }

  void setFrame(const FrameImages& host_frame) override { frame_ = host_frame; }

  void collectBandBlocks(const CameraView& cam, const IntegrationSettings& s, int stride,
                         std::vector<BlockCoord>& out) override {
    const int rows = (frame_.height + stride - 1) / stride;
    std::vector<std::vector<BlockCoord>> per_worker(parallelWorkers());
    std::vector<std::vector<BlockCoord>> recent_per_worker(parallelWorkers());
    parallelFor(rows, kRowsPerChunk, threads_, [&](int begin, int end, int worker) {
      auto& found = per_worker[worker];
      auto& recent = recent_per_worker[worker];
      if (recent.empty()) recent.assign(kRecentBlocks, BlockCoord{INT_MIN, INT_MIN, INT_MIN});
      auto emit = [&](BlockCoord c) {
        BlockCoord& slot = recent[hashBlock(c) & (kRecentBlocks - 1)];
        if (slot == c) return;
        slot = c;
        found.push_back(c);
      };
      for (int row = begin; row < end; ++row) {
        for (int u = 0; u < frame_.width; u += stride) visitBandBlocks(frame_, cam, s, u, row * stride, emit);
      }
    });
    out.clear();
    for (const auto& found : per_worker) out.insert(out.end(), found.begin(), found.end());
  }

  FrameUpdateReport updateBlocks(const CameraView& cam, const IntegrationSettings& s,
                                 const std::vector<BlockRef>& blocks, int sign, std::vector<uint8_t>& empty) override {
    empty.assign(blocks.size(), 0);
    std::vector<int> overflow(parallelWorkers(), 0), underflow(parallelWorkers(), 0);
    parallelFor(static_cast<int>(blocks.size()), kBlocksPerChunk, threads_, [&](int begin, int end, int worker) {
      const int flags = updateChunk(pool_.data(), blocks.data(), begin, end, frame_, cam, s, sign, empty.data());
      overflow[worker] |= flags & kWeightOverflow;
      underflow[worker] |= flags & kWeightUnderflow;
    });
    FrameUpdateReport report;
    report.weight_overflow = std::any_of(overflow.begin(), overflow.end(), [](int f) { return f != 0; });
    report.weight_underflow = std::any_of(underflow.begin(), underflow.end(), [](int f) { return f != 0; });
    return report;
  }

  void readBlocks(const std::vector<int32_t>& slots, Voxel* out) const override {
    for (size_t i = 0; i < slots.size(); ++i) {
      std::memcpy(out + i * kBlockVoxels, pool_.data() + static_cast<size_t>(slots[i]) * kBlockVoxels,
                  sizeof(Voxel) * kBlockVoxels);
    }
  }
  void writeBlocks(const std::vector<int32_t>& slots, const Voxel* in) override {
    for (size_t i = 0; i < slots.size(); ++i) {
      Voxel* dst = pool_.data() + static_cast<size_t>(slots[i]) * kBlockVoxels;
      if (in == nullptr) {
        std::memset(static_cast<void*>(dst), 0, sizeof(Voxel) * kBlockVoxels);
      } else {
        std::memcpy(dst, in + i * kBlockVoxels, sizeof(Voxel) * kBlockVoxels);
      }
    }
  }
  const Voxel* hostPool() const override { return pool_.data(); }

  void raycast(const std::vector<HashEntry>& table, uint64_t /*table_version*/, const CameraView& cam,
               const TileDepthRanges& ranges, int /*tiles*/, float voxel_size, float truncation, float max_depth,
               RaycastPixel* out) override {
    const VolumeView vol{{table.data(), static_cast<uint32_t>(table.size() - 1)}, pool_.data(), voxel_size, truncation};
    parallelFor(cam.height, kRowsPerChunk, threads_, [&](int begin, int end, int) {
      for (int v = begin; v < end; ++v) {
        for (int u = 0; u < cam.width; ++u) out[v * cam.width + u] = raycastPixel(vol, cam, ranges, max_depth, u, v);
      }
    });
  }

 private:
  int threads_;
  VoxelPool pool_;
  FrameImages frame_{};
};

}  // namespace

std::unique_ptr<VolumeBackend> makeCpuBackend(int threads) { return std::make_unique<CpuBackend>(threads); }

}  // namespace rekon::volume
