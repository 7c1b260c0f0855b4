#pragma once
// What a compute backend does for the TSDF volume. The volume (host code)
// owns the block hash, the slot allocation and the host store; a backend owns
// the voxel pool (host RAM or GPU memory) and runs the shared kernels of
// volume_kernels.hpp over it. Backends: CPU (threads) and CUDA (cuda/).
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "rekon/mapper/volume/volume_kernels.hpp"

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
// Every CUDA call of it is checked: a failure throws rekon::Error naming the
// call's purpose, file and line (kernel faults are synchronised after each launch).
std::unique_ptr<VolumeBackend> makeCudaBackend();
// Logs (spdlog) a CUDA failure that cannot be thrown: freeing GPU memory in a destructor.
void logCudaCleanupFailure(const std::string& line);
#endif

// What the CUDA driver says about this machine.
struct CudaProbe {
  int devices = 0;
  // True when a driver is installed but failed (too old for the runtime,
  // not initialisable, ...): not merely "no device".
  bool driver_error = false;
  std::string detail;  // why no device is usable, one line; empty when devices > 0
};
// Asks the driver (cudaGetDeviceCount, cudaDriverGetVersion). Without the CUDA
// backend built: 0 devices, "rekon was built without CUDA".
CudaProbe probeCudaDevices();

// Runs both backends in lockstep on two small synthetic frames (one with
// color only, one with color and per-pixel weights, holes, a NaN and a pixel
// beyond max_depth): integrate A, integrate B, grow the pool, de-integrate B,
// de-integrate A. After each step it compares the band blocks each backend
// finds, the update reports, the empty-block flags and every voxel (SDF sum,
// weight, r, g, b) exactly. Returns "" when they agree, else one line naming
// the first difference. Exceptions of either backend propagate.
std::string compareBackendsOnSyntheticFrames(VolumeBackend& reference, VolumeBackend& candidate);

// "cpu", "cuda" or "auto". auto: CUDA only when a device is present and the
// CUDA backend passes compareBackendsOnSyntheticFrames against the CPU backend
// (once per process); otherwise the CPU backend, with one warning line saying
// why when a driver error, a mismatch or a CUDA error was the reason. cuda:
// the same conditions throw rekon::Error instead.
std::unique_ptr<VolumeBackend> makeBackend(const std::string& choice, int cpu_threads);
// Backends usable in this process: always "cpu", plus "cuda" with a device
// (listed even if its self-check fails, so that tests of it fail loudly).
std::vector<std::string> availableBackends();

}  // namespace rekon::volume
