// The CUDA backend of the TSDF volume: launches of the shared kernels in
// services/mapper/volume/include/rekon/volume/volume_kernels.hpp over a voxel
// pool in GPU memory. The host keeps the block hash; it is mirrored to the
// device for ray casting whenever it changed.
#include <cuda_runtime.h>

#include <algorithm>
#include <stdexcept>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/volume/volume_backend.hpp"

namespace rekon::volume {
namespace {

void check(cudaError_t status, const char* what) {
  if (status != cudaSuccess) {
    throw Error(std::string("volume (CUDA): ") + what + " failed: " + cudaGetErrorString(status));
  }
}

// A growable device array (raw CUDA memory).
template <typename T>
class DeviceArray {
 public:
  DeviceArray() = default;
  DeviceArray(const DeviceArray&) = delete;
  DeviceArray& operator=(const DeviceArray&) = delete;
  ~DeviceArray() { cudaFree(data_); }
  T* data() const { return data_; }
  size_t size() const { return size_; }
  // Keeps the first min(old, n) elements when `keep` is set.
  void resize(size_t n, bool keep) {
    if (n == size_) return;
    T* fresh = nullptr;
    if (n > 0) {
      const cudaError_t status = cudaMalloc(&fresh, n * sizeof(T));
      if (status != cudaSuccess) {
        throw Error("volume (CUDA): cannot allocate " + std::to_string((n * sizeof(T)) >> 20) +
                    " MiB of GPU memory; lower volume.streaming_radius or volume.block_capacity");
      }
    }
    if (keep && data_ && fresh) check(cudaMemcpy(fresh, data_, std::min(n, size_) * sizeof(T), cudaMemcpyDeviceToDevice), "pool copy");
    cudaFree(data_);
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

__global__ void collectKernel(FrameImages frame, CameraView cam, IntegrationSettings s, int stride, BlockCoord* out,
                              int capacity, int* count) {
  const int u = (blockIdx.x * blockDim.x + threadIdx.x) * stride;
  const int v = (blockIdx.y * blockDim.y + threadIdx.y) * stride;
  if (u >= frame.width || v >= frame.height) return;
  visitBandBlocks(frame, cam, s, u, v, [&](BlockCoord c) {
    const int i = atomicAdd(count, 1);
    if (i < capacity) out[i] = c;
  });
}

// One CUDA thread block per voxel block, one thread per voxel.
__global__ void updateKernel(Voxel* pool, const BlockRef* blocks, FrameImages frame, CameraView cam,
                             IntegrationSettings s, int sign, uint8_t* empty, int* flags) {
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
// per voxel block, so that streaming moves many blocks with one transfer.
__global__ void gatherBlocks(const Voxel* pool, const int32_t* slots, Voxel* staging) {
  const int i = blockIdx.x, v = threadIdx.x;
  staging[static_cast<size_t>(i) * kBlockVoxels + v] = pool[static_cast<size_t>(slots[i]) * kBlockVoxels + v];
}
__global__ void scatterBlocks(Voxel* pool, const int32_t* slots, const Voxel* staging) {
  const int i = blockIdx.x, v = threadIdx.x;
  Voxel& dst = pool[static_cast<size_t>(slots[i]) * kBlockVoxels + v];
  if (staging) {
    dst = staging[static_cast<size_t>(i) * kBlockVoxels + v];
  } else {
    dst = Voxel{0, {0u, 0u}};
  }
}

__global__ void raycastKernel(VolumeView vol, CameraView cam, TileDepthRanges ranges, float max_depth, RaycastPixel* out) {
  const int u = blockIdx.x * blockDim.x + threadIdx.x;
  const int v = blockIdx.y * blockDim.y + threadIdx.y;
  if (u >= cam.width || v >= cam.height) return;
  out[v * cam.width + u] = raycastPixel(vol, cam, ranges, max_depth, u, v);
}

class CudaBackend final : public VolumeBackend {
 public:
  std::string name() const override { return "cuda"; }

  void resizePool(int32_t blocks) override { pool_.resize(static_cast<size_t>(blocks) * kBlockVoxels, true); }

  void setFrame(const FrameImages& host) override {
    const size_t pixels = static_cast<size_t>(host.width) * host.height;
    depth_.ensure(pixels);
    check(cudaMemcpy(depth_.data(), host.depth, pixels * sizeof(float), cudaMemcpyHostToDevice), "depth upload");
    if (host.bgr) {
      color_.ensure(pixels * 3);
      check(cudaMemcpy(color_.data(), host.bgr, pixels * 3, cudaMemcpyHostToDevice), "color upload");
    }
    if (host.weights) {
      weights_.ensure(pixels);
      check(cudaMemcpy(weights_.data(), host.weights, pixels * sizeof(float), cudaMemcpyHostToDevice), "weights upload");
    }
    frame_ = {depth_.data(), host.bgr ? color_.data() : nullptr, host.weights ? weights_.data() : nullptr, host.width,
              host.height};
  }

  void collectBandBlocks(const CameraView& cam, const IntegrationSettings& s, int stride,
                         std::vector<BlockCoord>& out) override {
    const int cols = (frame_.width + stride - 1) / stride, rows = (frame_.height + stride - 1) / stride;
    // Each ray segment of 2 * truncation crosses at most this many blocks.
    const int per_ray = 3 * (static_cast<int>(2.f * s.truncation / (kBlockSide * s.voxel_size)) + 2);
    const int capacity = cols * rows * per_ray;
    candidates_.ensure(capacity);
    counter_.ensure(1);
    check(cudaMemset(counter_.data(), 0, sizeof(int)), "counter reset");
    const dim3 threads(16, 16), grid((cols + 15) / 16, (rows + 15) / 16);
    collectKernel<<<grid, threads>>>(frame_, cam, s, stride, candidates_.data(), capacity, counter_.data());
    check(cudaGetLastError(), "band collection launch");
    int count = 0;
    check(cudaMemcpy(&count, counter_.data(), sizeof(int), cudaMemcpyDeviceToHost), "band collection");
    out.resize(std::min(count, capacity));
    check(cudaMemcpy(out.data(), candidates_.data(), out.size() * sizeof(BlockCoord), cudaMemcpyDeviceToHost),
          "band download");
  }

  FrameUpdateReport updateBlocks(const CameraView& cam, const IntegrationSettings& s,
                                 const std::vector<BlockRef>& blocks, int sign, std::vector<uint8_t>& empty) override {
    const int n = static_cast<int>(blocks.size());
    empty.assign(blocks.size(), 0);
    FrameUpdateReport report;
    if (n == 0) return report;
    refs_.ensure(n);
    empty_.ensure(n);
    counter_.ensure(1);
    check(cudaMemcpy(refs_.data(), blocks.data(), n * sizeof(BlockRef), cudaMemcpyHostToDevice), "block list upload");
    check(cudaMemset(counter_.data(), 0, sizeof(int)), "flag reset");
    updateKernel<<<n, dim3(kBlockSide, kBlockSide, kBlockSide)>>>(pool_.data(), refs_.data(), frame_, cam, s, sign, empty_.data(), counter_.data());
    check(cudaGetLastError(), "update launch");
    int flags = 0;
    check(cudaMemcpy(&flags, counter_.data(), sizeof(int), cudaMemcpyDeviceToHost), "update");
    check(cudaMemcpy(empty.data(), empty_.data(), n, cudaMemcpyDeviceToHost), "empty flags download");
    report.weight_overflow = flags & 1;
    report.weight_underflow = flags & 2;
    return report;
  }

  void readBlocks(const std::vector<int32_t>& slots, Voxel* out) const override {
    if (slots.empty()) return;
    const size_t voxels = slots.size() * kBlockVoxels;
    slots_.ensure(slots.size());
    staging_.ensure(voxels);
    check(cudaMemcpy(slots_.data(), slots.data(), slots.size() * sizeof(int32_t), cudaMemcpyHostToDevice), "slot upload");
    gatherBlocks<<<static_cast<unsigned>(slots.size()), kBlockVoxels>>>(pool_.data(), slots_.data(), staging_.data());
    check(cudaGetLastError(), "block gather launch");
    check(cudaMemcpy(out, staging_.data(), voxels * sizeof(Voxel), cudaMemcpyDeviceToHost), "block download");
  }
  void writeBlocks(const std::vector<int32_t>& slots, const Voxel* in) override {
    if (slots.empty()) return;
    const size_t voxels = slots.size() * kBlockVoxels;
    slots_.ensure(slots.size());
    check(cudaMemcpy(slots_.data(), slots.data(), slots.size() * sizeof(int32_t), cudaMemcpyHostToDevice), "slot upload");
    if (in) {
      staging_.ensure(voxels);
      check(cudaMemcpy(staging_.data(), in, voxels * sizeof(Voxel), cudaMemcpyHostToDevice), "block upload");
    }
    scatterBlocks<<<static_cast<unsigned>(slots.size()), kBlockVoxels>>>(pool_.data(), slots_.data(),
                                                                          in ? staging_.data() : nullptr);
    check(cudaGetLastError(), "block scatter launch");
  }
  const Voxel* hostPool() const override { return nullptr; }

  void raycast(const std::vector<HashEntry>& table, uint64_t table_version, const CameraView& cam,
               const TileDepthRanges& host_ranges, int tiles, float voxel_size, float truncation, float max_depth,
               RaycastPixel* out) override {
    range_near_.ensure(tiles);
    range_far_.ensure(tiles);
    check(cudaMemcpy(range_near_.data(), host_ranges.near, tiles * sizeof(float), cudaMemcpyHostToDevice), "ranges upload");
    check(cudaMemcpy(range_far_.data(), host_ranges.far, tiles * sizeof(float), cudaMemcpyHostToDevice), "ranges upload");
    const TileDepthRanges ranges{range_near_.data(), range_far_.data(), host_ranges.tiles_x, host_ranges.tile};
    if (table_version != mirrored_version_ || table_.size() != table.size()) {
      table_.resize(table.size(), false);
      check(cudaMemcpy(table_.data(), table.data(), table.size() * sizeof(HashEntry), cudaMemcpyHostToDevice),
            "hash mirror");
      mirrored_version_ = table_version;
    }
    const size_t pixels = static_cast<size_t>(cam.width) * cam.height;
    image_.ensure(pixels);
    const VolumeView vol{{table_.data(), static_cast<uint32_t>(table.size() - 1)}, pool_.data(), voxel_size, truncation};
    const dim3 threads(16, 16), grid((cam.width + 15) / 16, (cam.height + 15) / 16);
    raycastKernel<<<grid, threads>>>(vol, cam, ranges, max_depth, image_.data());
    check(cudaGetLastError(), "raycast launch");
    check(cudaMemcpy(out, image_.data(), pixels * sizeof(RaycastPixel), cudaMemcpyDeviceToHost), "raycast download");
  }

 private:
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

int cudaDeviceCount() {
  int count = 0;
  if (cudaGetDeviceCount(&count) != cudaSuccess) {
    cudaGetLastError();  // clear the sticky "no driver" status
    return 0;
  }
  return count;
}

}  // namespace rekon::volume
