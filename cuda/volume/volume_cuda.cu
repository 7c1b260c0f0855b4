// The CUDA backend of the TSDF volume: launches of the shared kernels in
// services/mapper/include/rekon/mapper/volume/volume_kernels.hpp over a voxel
// pool in GPU memory. The host keeps the block hash; it is mirrored to the
// device for ray casting whenever it changed.
//
// Compiled with --fmad=false (cuda/CMakeLists.txt): the kernels then run the
// same IEEE single-precision operations in the same order as the CPU backend,
// so both produce identical voxels (see tests/volume/test_volume_cuda_oracle.cpp).
#include <cuda_runtime.h>

#include <algorithm>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/mapper/volume/volume_backend.hpp"

namespace rekon::volume {
namespace {

constexpr const char* baseName(const char* path) {
  const char* base = path;
  for (const char* p = path; *p != '\0'; ++p) {
    if (*p == '/') base = p + 1;
  }
  return base;
}

std::string cudaFailure(cudaError_t status, const char* what, const char* file, int line) {
  return std::string("volume (CUDA): ") + what + " failed at " + baseName(file) + ":" + std::to_string(line) + ": " +
         cudaGetErrorName(status) + " (" + cudaGetErrorString(status) + ")";
}

void checkCuda(cudaError_t status, const char* what, const char* file, int line) {
  if (status != cudaSuccess) {
    throw Error(cudaFailure(status, what, file, line) + "; set volume.backend to cpu to run without the GPU");
  }
}

}  // namespace
}  // namespace rekon::volume

// Every CUDA runtime call goes through one of these two.
#define REKON_CUDA_CHECK(call, what) ::rekon::volume::checkCuda((call), (what), __FILE__, __LINE__)
// After a kernel launch: a bad launch (configuration, resources) from
// cudaGetLastError, then a fault during its execution from the synchronisation,
// so that either is reported at this launch and not at some later copy.
#define REKON_CUDA_CHECK_KERNEL(kernel_name)                                                               \
  do {                                                                                                     \
    ::rekon::volume::checkCuda(cudaGetLastError(), "launch of " kernel_name, __FILE__, __LINE__);          \
    ::rekon::volume::checkCuda(cudaDeviceSynchronize(), "execution of " kernel_name, __FILE__, __LINE__); \
  } while (0)

namespace rekon::volume {
namespace {

// Threads per CUDA block of the per-pixel kernels (a 16x16 tile of pixels).
constexpr int kTileSide = 16;
constexpr int kTileThreads = kTileSide * kTileSide;

// Copies `bytes` (nothing, and no CUDA call, when 0: the pointers may then be null).
void copyBytes(void* dst, const void* src, size_t bytes, cudaMemcpyKind kind, const char* what, const char* file,
               int line) {
  if (bytes == 0) return;
  checkCuda(cudaMemcpy(dst, src, bytes, kind), what, file, line);
}
#define REKON_CUDA_COPY(dst, src, bytes, kind, what) copyBytes((dst), (src), (bytes), (kind), (what), __FILE__, __LINE__)

// A growable device array (raw CUDA memory).
template <typename T>
class DeviceArray {
 public:
  DeviceArray() = default;
  DeviceArray(const DeviceArray&) = delete;
  DeviceArray& operator=(const DeviceArray&) = delete;
  ~DeviceArray() {
    if (data_ == nullptr) return;
    const cudaError_t status = cudaFree(data_);
    // At process exit the runtime may already be unloaded: nothing is left to free.
    if (status != cudaSuccess && status != cudaErrorCudartUnloading) {
      logCudaCleanupFailure(cudaFailure(status, "freeing GPU memory", __FILE__, __LINE__));
    }
  }
  T* data() const { return data_; }
  size_t size() const { return size_; }
  // Keeps the first min(old, n) elements when `keep` is set.
  void resize(size_t n, bool keep) {
    if (n == size_) return;
    T* fresh = nullptr;
    if (n > 0) {
      const cudaError_t status = cudaMalloc(&fresh, n * sizeof(T));
      if (status != cudaSuccess) {
        cudaGetLastError();  // an allocation failure is not sticky; do not let it surface at the next launch
        throw Error(cudaFailure(status, "cudaMalloc", __FILE__, __LINE__) + ": cannot allocate " +
                    std::to_string((n * sizeof(T)) >> 20) +
                    " MiB of GPU memory; lower volume.streaming_radius or volume.block_capacity");
      }
    }
    if (keep && data_ != nullptr && fresh != nullptr) {
      REKON_CUDA_COPY(fresh, data_, std::min(n, size_) * sizeof(T), cudaMemcpyDeviceToDevice, "pool copy on growth");
    }
    if (data_ != nullptr) REKON_CUDA_CHECK(cudaFree(data_), "freeing the old GPU array");
    data_ = fresh;
    size_ = n;
  }
  void ensure(size_t n) {
    if (n > size_) resize(n, false);
  }

 private:
  T* data_ = nullptr;
  size_t size_ = 0;
};

// Counts every band block in *count, stores the first `capacity` of them:
// the host compares the count with the capacity and relaunches when it was short.
__global__ void __launch_bounds__(kTileThreads)
    collectKernel(FrameImages frame, CameraView cam, IntegrationSettings s, int stride, BlockCoord* out, int capacity,
                  int* count) {
  const int u = (blockIdx.x * blockDim.x + threadIdx.x) * stride;
  const int v = (blockIdx.y * blockDim.y + threadIdx.y) * stride;
  if (u >= frame.width || v >= frame.height) return;
  visitBandBlocks(frame, cam, s, u, v, [&](BlockCoord c) {
    const int i = atomicAdd(count, 1);
    if (i < capacity) out[i] = c;
  });
}

// One CUDA thread block per voxel block, one thread per voxel: the thread
// index is the voxel's position, and __syncthreads_or spans the whole block,
// so the kernel must be launched with exactly kBlockSide^3 threads.
__global__ void __launch_bounds__(kBlockVoxels)
    updateKernel(Voxel* pool, const BlockRef* blocks, FrameImages frame, CameraView cam, IntegrationSettings s,
                 int sign, uint8_t* empty, int* flags) {
  const BlockRef ref = blocks[blockIdx.x];
  const int x = threadIdx.x, y = threadIdx.y, z = threadIdx.z;
  Voxel& v = pool[static_cast<size_t>(ref.slot) * kBlockVoxels + localIndex(x, y, z)];
  bool observed = false;
  const int status =
      updateVoxel(v, blockInCamera(cam, ref.coord, s.voxel_size), x, y, z, frame, cam, s, sign, observed);
  if (status == kWeightOverflow) atomicOr(flags, 1);
  if (status == kWeightUnderflow) atomicOr(flags, 2);
  const int occupied = __syncthreads_or(blockOccupiedAfter(v, status, observed, sign));
  if (x == 0 && y == 0 && z == 0) empty[blockIdx.x] = occupied ? 0 : 1;
}

// Block copies between the pool and a dense staging array, one CUDA block
// per voxel block and one thread per voxel (launched with kBlockVoxels
// threads), so that streaming moves many blocks with one transfer.
__global__ void __launch_bounds__(kBlockVoxels) gatherBlocks(const Voxel* pool, const int32_t* slots, Voxel* staging) {
  const int i = blockIdx.x, v = threadIdx.x;
  staging[static_cast<size_t>(i) * kBlockVoxels + v] = pool[static_cast<size_t>(slots[i]) * kBlockVoxels + v];
}
__global__ void __launch_bounds__(kBlockVoxels)
    scatterBlocks(Voxel* pool, const int32_t* slots, const Voxel* staging) {
  const int i = blockIdx.x, v = threadIdx.x;
  Voxel& dst = pool[static_cast<size_t>(slots[i]) * kBlockVoxels + v];
  if (staging) {
    dst = staging[static_cast<size_t>(i) * kBlockVoxels + v];
  } else {
    dst = Voxel{0, {0u, 0u}};
  }
}

__global__ void __launch_bounds__(kTileThreads)
    raycastKernel(VolumeView vol, CameraView cam, TileDepthRanges ranges, float max_depth, RaycastPixel* out) {
  const int u = blockIdx.x * blockDim.x + threadIdx.x;
  const int v = blockIdx.y * blockDim.y + threadIdx.y;
  if (u >= cam.width || v >= cam.height) return;
  out[v * cam.width + u] = raycastPixel(vol, cam, ranges, max_depth, u, v);
}

dim3 tileGrid(int width, int height) {
  return dim3(static_cast<unsigned>((width + kTileSide - 1) / kTileSide),
              static_cast<unsigned>((height + kTileSide - 1) / kTileSide));
}

class CudaBackend final : public VolumeBackend {
 public:
  std::string name() const override { return "cuda"; }

  void resizePool(int32_t blocks) override { pool_.resize(static_cast<size_t>(blocks) * kBlockVoxels, true); }

  void setFrame(const FrameImages& host) override {
    const size_t pixels = static_cast<size_t>(host.width) * host.height;
    depth_.ensure(pixels);
    REKON_CUDA_COPY(depth_.data(), host.depth, pixels * sizeof(float), cudaMemcpyHostToDevice, "depth upload");
    if (host.bgr) {
      color_.ensure(pixels * 3);
      REKON_CUDA_COPY(color_.data(), host.bgr, pixels * 3, cudaMemcpyHostToDevice, "color upload");
    }
    if (host.weights) {
      weights_.ensure(pixels);
      REKON_CUDA_COPY(weights_.data(), host.weights, pixels * sizeof(float), cudaMemcpyHostToDevice, "weights upload");
    }
    frame_ = {depth_.data(), host.bgr ? color_.data() : nullptr, host.weights ? weights_.data() : nullptr, host.width,
              host.height};
  }

  void collectBandBlocks(const CameraView& cam, const IntegrationSettings& s, int stride,
                         std::vector<BlockCoord>& out) override {
    out.clear();
    const int cols = (frame_.width + stride - 1) / stride, rows = (frame_.height + stride - 1) / stride;
    if (cols <= 0 || rows <= 0) return;
    // A first guess of the candidates per sampled pixel (a ray segment of 2 *
    // truncation crosses about this many blocks); the kernel counts them all,
    // so a short buffer is grown to the exact count and the pass repeated.
    const size_t per_ray = 3 * (static_cast<size_t>(2.f * s.truncation / (kBlockSide * s.voxel_size)) + 2);
    candidates_.ensure(static_cast<size_t>(cols) * rows * per_ray);
    counter_.ensure(1);
    for (int attempt = 0; attempt < 2; ++attempt) {
      const int capacity = static_cast<int>(std::min<size_t>(candidates_.size(), kMaxCandidates));
      REKON_CUDA_CHECK(cudaMemset(counter_.data(), 0, sizeof(int)), "band counter reset");
      collectKernel<<<tileGrid(cols, rows), dim3(kTileSide, kTileSide)>>>(frame_, cam, s, stride, candidates_.data(),
                                                                          capacity, counter_.data());
      REKON_CUDA_CHECK_KERNEL("collectKernel");
      int count = 0;
      REKON_CUDA_COPY(&count, counter_.data(), sizeof(int), cudaMemcpyDeviceToHost, "band count download");
      if (count < 0 || static_cast<size_t>(count) >= kMaxCandidates) {
        throw Error("volume (CUDA): a frame's truncation band crosses " + std::to_string(count) +
                    " block candidates, more than the " + std::to_string(kMaxCandidates) +
                    " one pass can hold; raise volume.allocation_stride or lower volume.truncation");
      }
      if (count <= capacity) {
        out.resize(static_cast<size_t>(count));
        REKON_CUDA_COPY(out.data(), candidates_.data(), out.size() * sizeof(BlockCoord), cudaMemcpyDeviceToHost,
                        "band download");
        return;
      }
      candidates_.ensure(static_cast<size_t>(count));
    }
    // The kernel is deterministic in what it counts: a second short pass is a bug, never data to drop.
    throw Error("volume (CUDA): internal error: the band block count changed between two passes over the same frame");
  }

  FrameUpdateReport updateBlocks(const CameraView& cam, const IntegrationSettings& s,
                                 const std::vector<BlockRef>& blocks, int sign, std::vector<uint8_t>& empty) override {
    const size_t n = blocks.size();
    empty.assign(n, 0);
    FrameUpdateReport report;
    if (n == 0) return report;
    if (n > kMaxGridBlocks) {
      throw Error("volume (CUDA): " + std::to_string(n) + " blocks in one update exceed the launch limit of " +
                  std::to_string(kMaxGridBlocks) + "; lower volume.truncation or volume.max_depth");
    }
    refs_.ensure(n);
    empty_.ensure(n);
    counter_.ensure(1);
    REKON_CUDA_COPY(refs_.data(), blocks.data(), n * sizeof(BlockRef), cudaMemcpyHostToDevice, "block list upload");
    REKON_CUDA_CHECK(cudaMemset(counter_.data(), 0, sizeof(int)), "update flag reset");
    updateKernel<<<static_cast<unsigned>(n), dim3(kBlockSide, kBlockSide, kBlockSide)>>>(
        pool_.data(), refs_.data(), frame_, cam, s, sign, empty_.data(), counter_.data());
    REKON_CUDA_CHECK_KERNEL("updateKernel");
    int flags = 0;
    REKON_CUDA_COPY(&flags, counter_.data(), sizeof(int), cudaMemcpyDeviceToHost, "update flag download");
    REKON_CUDA_COPY(empty.data(), empty_.data(), n, cudaMemcpyDeviceToHost, "empty flag download");
    report.weight_overflow = flags & 1;
    report.weight_underflow = flags & 2;
    return report;
  }

  void readBlocks(const std::vector<int32_t>& slots, Voxel* out) const override {
    if (slots.empty()) return;
    checkBlockCount(slots.size());
    const size_t voxels = slots.size() * kBlockVoxels;
    slots_.ensure(slots.size());
    staging_.ensure(voxels);
    REKON_CUDA_COPY(slots_.data(), slots.data(), slots.size() * sizeof(int32_t), cudaMemcpyHostToDevice,
                    "slot upload");
    gatherBlocks<<<static_cast<unsigned>(slots.size()), kBlockVoxels>>>(pool_.data(), slots_.data(), staging_.data());
    REKON_CUDA_CHECK_KERNEL("gatherBlocks");
    REKON_CUDA_COPY(out, staging_.data(), voxels * sizeof(Voxel), cudaMemcpyDeviceToHost, "block download");
  }
  void writeBlocks(const std::vector<int32_t>& slots, const Voxel* in) override {
    if (slots.empty()) return;
    checkBlockCount(slots.size());
    const size_t voxels = slots.size() * kBlockVoxels;
    slots_.ensure(slots.size());
    REKON_CUDA_COPY(slots_.data(), slots.data(), slots.size() * sizeof(int32_t), cudaMemcpyHostToDevice,
                    "slot upload");
    if (in) {
      staging_.ensure(voxels);
      REKON_CUDA_COPY(staging_.data(), in, voxels * sizeof(Voxel), cudaMemcpyHostToDevice, "block upload");
    }
    scatterBlocks<<<static_cast<unsigned>(slots.size()), kBlockVoxels>>>(pool_.data(), slots_.data(),
                                                                          in ? staging_.data() : nullptr);
    REKON_CUDA_CHECK_KERNEL("scatterBlocks");
  }
  const Voxel* hostPool() const override { return nullptr; }

  void raycast(const std::vector<HashEntry>& table, uint64_t table_version, const CameraView& cam,
               const TileDepthRanges& host_ranges, int tiles, float voxel_size, float truncation, float max_depth,
               RaycastPixel* out) override {
    const size_t pixels = static_cast<size_t>(cam.width) * cam.height;
    if (pixels == 0 || tiles <= 0 || table.empty()) {
      throw Error("volume (CUDA): internal error: raycast of a " + std::to_string(cam.width) + "x" +
                  std::to_string(cam.height) + " image with " + std::to_string(tiles) + " tiles and a hash table of " +
                  std::to_string(table.size()) + " entries");
    }
    range_near_.ensure(tiles);
    range_far_.ensure(tiles);
    REKON_CUDA_COPY(range_near_.data(), host_ranges.near, tiles * sizeof(float), cudaMemcpyHostToDevice,
                    "tile range upload");
    REKON_CUDA_COPY(range_far_.data(), host_ranges.far, tiles * sizeof(float), cudaMemcpyHostToDevice,
                    "tile range upload");
    const TileDepthRanges ranges{range_near_.data(), range_far_.data(), host_ranges.tiles_x, host_ranges.tile};
    if (table_version != mirrored_version_ || table_.size() != table.size()) {
      table_.resize(table.size(), false);
      REKON_CUDA_COPY(table_.data(), table.data(), table.size() * sizeof(HashEntry), cudaMemcpyHostToDevice,
                      "hash table mirror");
      mirrored_version_ = table_version;
    }
    image_.ensure(pixels);
    const VolumeView vol{{table_.data(), static_cast<uint32_t>(table.size() - 1)}, pool_.data(), voxel_size, truncation};
    raycastKernel<<<tileGrid(cam.width, cam.height), dim3(kTileSide, kTileSide)>>>(vol, cam, ranges, max_depth,
                                                                                     image_.data());
    REKON_CUDA_CHECK_KERNEL("raycastKernel");
    REKON_CUDA_COPY(out, image_.data(), pixels * sizeof(RaycastPixel), cudaMemcpyDeviceToHost, "raycast download");
  }

 private:
  // Grid x-dimension limit of every device since compute capability 3.0.
  static constexpr size_t kMaxGridBlocks = (1ull << 31) - 1;
  // The band counter is an int: stay clear of its overflow.
  static constexpr size_t kMaxCandidates = 1ull << 30;

  static void checkBlockCount(size_t blocks) {
    if (blocks > kMaxGridBlocks) {
      throw Error("volume (CUDA): " + std::to_string(blocks) + " blocks in one transfer exceed the launch limit of " +
                  std::to_string(kMaxGridBlocks) + "; lower volume.streaming_radius");
    }
  }

  DeviceArray<Voxel> pool_;
  DeviceArray<float> depth_, weights_, range_near_, range_far_;
  DeviceArray<uint8_t> color_, empty_;
  DeviceArray<BlockCoord> candidates_;
  DeviceArray<BlockRef> refs_;
  DeviceArray<int> counter_;
  DeviceArray<HashEntry> table_;
  // Staging for block transfers; mutable because reading blocks is logically const.
  mutable DeviceArray<int32_t> slots_;
  mutable DeviceArray<Voxel> staging_;
  DeviceArray<RaycastPixel> image_;
  uint64_t mirrored_version_ = ~0ull;
  FrameImages frame_{};
};

}  // namespace

std::unique_ptr<VolumeBackend> makeCudaBackend() { return std::make_unique<CudaBackend>(); }

CudaProbe probeCudaDevices() {
  CudaProbe probe;
  int count = 0;
  const cudaError_t status = cudaGetDeviceCount(&count);
  cudaGetLastError();  // the status is reported below; do not leave it for the next call to find
  if (status == cudaSuccess && count > 0) {
    probe.devices = count;
    return probe;
  }
  int driver = 0;
  const cudaError_t driver_status = cudaDriverGetVersion(&driver);
  cudaGetLastError();
  // cudaDriverGetVersion reports 0 when no driver is installed: a machine without a GPU, not a failure.
  if (driver_status == cudaSuccess && driver == 0) {
    probe.detail = "no CUDA driver is installed";
    return probe;
  }
  if (status == cudaSuccess || status == cudaErrorNoDevice) {
    probe.detail = "the CUDA driver reports no device";
    return probe;
  }
  int runtime = 0;
  const bool runtime_known = cudaRuntimeGetVersion(&runtime) == cudaSuccess;
  probe.driver_error = true;
  probe.detail = std::string("cudaGetDeviceCount failed: ") + cudaGetErrorName(status) + " (" +
                 cudaGetErrorString(status) + "); driver version " +
                 (driver_status == cudaSuccess ? std::to_string(driver) : std::string("unknown")) +
                 ", runtime version " + (runtime_known ? std::to_string(runtime) : std::string("unknown"));
  return probe;
}

}  // namespace rekon::volume
