#pragma once
// What a compute backend does for the TSDF volume. The volume (host code)
// owns the block hash, the slot allocation and the host store; a backend owns
// the voxel pool (host RAM or GPU memory) and runs the shared kernels of
// volume_kernels.hpp over it. Backends: CPU (threads) and CUDA (cuda/).
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "rekon/volume/volume_kernels.hpp"

namespace rekon::volume {

// A block of this frame's truncation band, resolved to its pool slot.
struct BlockRef {
  BlockCoord coord;
  int32_t slot;
};

struct FrameUpdateReport {
  bool weight_overflow = false;   // some voxel would exceed kMaxVoxelWeight
  bool weight_underflow = false;  // de-integration of something never integrated
};

class VolumeBackend {
 public:
  virtual ~VolumeBackend() = default;
  virtual std::string name() const = 0;

  // Grows (or first allocates) the pool to `blocks` slots, keeping slots below the old size.
  virtual void resizePool(int32_t blocks) = 0;

  // Makes the frame current for the calls below (the CUDA backend uploads it).
  virtual void setFrame(const FrameImages& host_frame) = 0;
  // Blocks touched by the truncation band of every `stride`-th pixel of the
  // current frame; duplicates allowed.
  virtual void collectBandBlocks(const CameraView& cam, const IntegrationSettings& s, int stride,
                                 std::vector<BlockCoord>& out) = 0;
  // Integrates (sign +1) or de-integrates (-1) the current frame into the
  // listed blocks; empty[i] = 1 when the frame updated no voxel of block i
  // (integration) or block i holds no weight afterwards (de-integration).
  virtual FrameUpdateReport updateBlocks(const CameraView& cam, const IntegrationSettings& s,
                                         const std::vector<BlockRef>& blocks, int sign,
                                         std::vector<uint8_t>& empty) = 0;

  // Copies whole blocks (kBlockVoxels voxels each) out of / into the pool;
  // writeBlocks with null data zero-fills.
  virtual void readBlocks(const std::vector<int32_t>& slots, Voxel* out) const = 0;
  virtual void writeBlocks(const std::vector<int32_t>& slots, const Voxel* in) = 0;
  // The pool itself when it lives in host memory (CPU backend), else null.
  virtual const Voxel* hostPool() const = 0;

  // Ray casts the active volume; `table` is the host hash table (the CUDA
  // backend mirrors it when `table_version` changed); `host_ranges` holds
  // `tiles` host entries. Outputs are host arrays of width*height pixels.
  virtual void raycast(const std::vector<HashEntry>& table, uint64_t table_version, const CameraView& cam,
                       const TileDepthRanges& host_ranges, int tiles, float voxel_size, float truncation,
                       float max_depth, RaycastPixel* out) = 0;
};

std::unique_ptr<VolumeBackend> makeCpuBackend(int threads);
#ifdef REKON_VOLUME_WITH_CUDA
std::unique_ptr<VolumeBackend> makeCudaBackend();
int cudaDeviceCount();  // 0 when the driver reports none or fails
#endif

// "cpu", "cuda" or "auto" (CUDA when a device is present, else CPU; logged).
std::unique_ptr<VolumeBackend> makeBackend(const std::string& choice, int cpu_threads);
// Backends usable in this process: always "cpu", plus "cuda" with a device.
std::vector<std::string> availableBackends();

}  // namespace rekon::volume
