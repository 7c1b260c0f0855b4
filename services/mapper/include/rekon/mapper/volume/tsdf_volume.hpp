#pragma once
// The mapping core: a voxel-hashed TSDF (Voxel Hashing, Niessner et al. 2013)
// with exact de-integration (paper eq. 2), streaming of blocks between the
// active volume and a host store around a sphere (paper section 3), colored
// marching cubes and ray casting.
#include <opencv2/core/mat.hpp>

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/mapper/volume/volume_backend.hpp"

namespace rekon::volume {

class HostBlocks;

struct VolumeParams {
  static constexpr double kDefaultVoxelSize = 0.01;     // metres
  static constexpr double kDefaultTruncation = 0.04;    // metres
  static constexpr double kDefaultMaxDepth = 4.0;       // metres; farther pixels are ignored
  static constexpr int kDefaultBlockCapacity = 1 << 15; // initial active-pool size in blocks
  static constexpr double kDefaultStreamingRadius = 0;  // metres; 0 = never stream
  // A pixel weight of 1 counts as this many integer weight units: weights are
  // quantised to 1/32 so that sums stay exact integers. Keyframe weights
  // cos(theta)/Z^2 reach 1/32 at Z = 4 m, theta = 60 deg; a voxel holds up to
  // 2^21 units = 65535 observations of weight 1 (more is a loud error).
  static constexpr double kDefaultWeightUnits = 32;
  // Every stride-th pixel (in x and y) allocates blocks; at 4 m four pixels
  // (f = 585) are 2.7 cm apart, well below the 8 cm block size. Integration then updates every
  // voxel of those blocks from its own pixel.
  static constexpr int kDefaultAllocationStride = 4;

  double voxel_size = kDefaultVoxelSize;
  double truncation = kDefaultTruncation;
  double max_depth = kDefaultMaxDepth;
  int block_capacity = kDefaultBlockCapacity;
  bool grow_capacity = true;  // false: running out throws rekon::Error naming the number to raise
  double streaming_radius = kDefaultStreamingRadius;
  // Blocks outside the streaming sphere may stay active up to this many in
  // all (the active pool's budget); 0 = none stays: each streamAround moves
  // every block outside the sphere to the host store (those a correction
  // round brought in stay until then).
  int64_t active_max_blocks = 0;
  // Blocks of the host tier kept in memory; beyond, the farthest from the
  // streaming centre go to a spill file in spill_dir (0 = no budget).
  int64_t host_max_blocks = 0;
  std::string spill_dir;
  double weight_units = kDefaultWeightUnits;
  int allocation_stride = kDefaultAllocationStride;
  std::string backend = "auto";  // "auto", "cpu" or "cuda"
  int cpu_threads = 0;           // 0 = all hardware threads

  // Throws rekon::Error naming the setting and its valid range.
  void validate() const;
};

struct VolumeStats {
  int64_t blocks = 0;         // active + host store
  int64_t active_blocks = 0;  // in the backend's pool (GPU memory for CUDA)
  int64_t host_blocks = 0;          // in memory and on disk
  int64_t host_blocks_on_disk = 0;
  int64_t spilled_to_disk = 0;      // blocks moved host memory -> disk, in total
  int64_t read_back_from_disk = 0;  // blocks taken back from disk, in total
  int64_t peak_active_blocks = 0;
  int64_t block_capacity = 0;
  int64_t streamed_out = 0;  // blocks moved active -> host store, in total
  int64_t streamed_in = 0;   // blocks moved host store -> active, in total
  int64_t last_update_blocks = 0;  // blocks the last (de-)integration updated
  int64_t updated_blocks = 0;      // blocks (de-)integrations updated, in total
  int bytes_per_voxel = static_cast<int>(sizeof(Voxel));
  std::string backend;
};

struct RaycastImages {
  cv::Mat depth;    // CV_32F, metres along the camera z axis; 0 = no surface
  cv::Mat normals;  // CV_32FC3, unit normals in the world frame; 0 = none
  cv::Mat color;    // CV_8UC3, BGR
};

class TsdfVolume {
 public:
  explicit TsdfVolume(const VolumeParams& params = {});
  ~TsdfVolume();
  TsdfVolume(const TsdfVolume&) = delete;
  TsdfVolume& operator=(const TsdfVolume&) = delete;

  // depth_m: CV_32F metres (0 = none); color: CV_8UC3 BGR or empty; weights:
  // CV_32F per-pixel weights (1 = one ordinary observation) or empty. All of
  // intrinsics' size. Throws rekon::Error for a bad pose, size or type.
  void integrate(const cv::Mat& depth_m, const cv::Mat& color, const cv::Mat& weights, const Intrinsics& k,
                 const Pose& camera_to_world);
  // Exactly undoes integrate() with the same arguments (eq. 2): weights and
  // signed distances return bit for bit, color within rounding; blocks left
  // without weight are freed.
  void deintegrate(const cv::Mat& depth_m, const cv::Mat& color, const cv::Mat& weights, const Intrinsics& k,
                   const Pose& camera_to_world);

  // Brings the blocks whose centre lies within streaming_radius of `centre`
  // into the active volume; blocks outside the sphere move to the host store,
  // all of them without a budget (active_max_blocks 0), else only as many as
  // keep the pool within it, least recently updated first, in batches of a
  // sixteenth of the budget (radius 0: no-op). A (de-)integration brings in
  // the streamed-out blocks it updates wherever it is; with a budget it makes
  // room for them the same way, keeping the sphere around the last centre.
  void streamAround(const Eigen::Vector3d& centre);

  // Marching cubes over active and host blocks (those on disk read back); vertices are shared along
  // voxel edges, colors are RGB.
  Mesh extractMesh() const;
  // The same mesh in pieces of `blocks_per_piece` blocks (MeshPieces: each
  // piece's triangles index the vertices of the pieces before it), so that
  // neither the mesh nor the blocks on disk need to fit in memory at once;
  // sink(piece) writes it out (PlyWriter) or collects it (extractMesh).
  static constexpr int kMeshPieceBlocks = 8192;  // 48 MiB of voxels
  void extractMeshInPieces(const std::function<void(const Mesh&)>& sink, int blocks_per_piece = kMeshPieceBlocks) const;
  // Blocks whose mesh may have changed since the last call: (de-)integration
  // changes a block's voxels, and with them its own mesh and those of its
  // -x/-y/-z neighbours (their cubes reach into its first layer); blocks
  // freed are included (their mesh is now empty). Streaming changes no mesh.
  std::vector<BlockCoord> takeMeshChanges();
  // Each block's mesh on its own (marchingCubesPerBlock: its vertices equal
  // extractMesh()'s); a block that is not allocated gets an empty mesh.
  // Versions are left 0 for the caller. On max_workers of the pool's
  // threads (0: all; 1: the calling thread only, as mid-run updates use it,
  // so that they never take a core from the integration).
  std::vector<BlockMesh> meshBlocks(const std::vector<BlockCoord>& coords, int max_workers = 1) const;
  // Ray casts the active blocks (stream around the camera first).
  RaycastImages raycast(const Intrinsics& k, const Pose& camera_to_world) const;

  VolumeStats stats() const;
  const VolumeParams& params() const { return params_; }
  const std::string& backendName() const { return backend_name_; }

  // The voxels of a block (active or host), or false when it is not allocated.
  bool readBlock(const BlockCoord& coord, std::vector<Voxel>& voxels) const;
  // Coordinates of every allocated block (active and host), unordered.
  std::vector<BlockCoord> blockCoords() const;

 private:
  struct CoordHash {
    size_t operator()(const BlockCoord& c) const { return hashBlock(c); }
  };

  void update(const cv::Mat& depth_m, const cv::Mat& color, const cv::Mat& weights, const Intrinsics& k,
              const Pose& camera_to_world, int sign);
  // The band's blocks, those allocated for this frame last (from *fresh_begin on).
  std::vector<BlockRef> resolveBandBlocks(const std::vector<BlockCoord>& candidates, bool allocate, size_t* fresh_begin);
  int32_t takeSlot(const BlockCoord& coord);
  void releaseSlot(int32_t slot);
  void ensureCapacity(int64_t active_needed);
  void rehash(uint32_t table_size);
  void tableInsert(const BlockCoord& coord, int32_t slot);
  void tableErase(const BlockCoord& coord);
  int32_t tableFind(const BlockCoord& coord) const;
  void streamIn(const std::vector<BlockCoord>& coords, std::vector<int32_t>& slots);
  // Moves active blocks outside the sphere around centre to the host store:
  // all of them without a budget, else `excess` of them (see streamAround)
  // and never those of the latest update.
  void streamOutBeyond(const Eigen::Vector3d& centre, int64_t excess);
  // With a budget: streams out what `incoming` more blocks would take past it
  // (see streamAround), keeping the sphere around the last streaming centre.
  void makeRoom(int64_t incoming);
  // Allocated, active or host.
  bool exists(const BlockCoord& c) const;
  // `blocks` (allocated, each once) followed by their +x/+y/+z neighbours
  // that exist, whose voxels and vertices their cubes use (marchingCubesPerBlock, MeshPieces).
  std::vector<BlockCoord> withUpperNeighbours(std::vector<BlockCoord> blocks) const;
  // Voxels of each block of coords (active or host; every one must exist), copied when the pool is not on the host.
  void voxelPointers(const std::vector<BlockCoord>& coords, std::vector<const Voxel*>& data, std::vector<Voxel>& copied) const;

  VolumeParams params_;
  std::unique_ptr<VolumeBackend> backend_;
  std::string backend_name_;
  std::vector<HashEntry> table_;  // size a power of two, at least twice the pool
  uint64_t table_version_ = 0;
  std::vector<BlockCoord> slot_coord_;
  std::vector<uint8_t> slot_used_;
  std::vector<uint32_t> slot_stamp_;  // last update that touched the slot (dedup; least recent streams out first)
  std::vector<int32_t> free_slots_;
  uint32_t frame_stamp_ = 0;
  Eigen::Vector3d streaming_centre_ = Eigen::Vector3d::Zero();  // of the last streamAround
  int64_t active_blocks_ = 0;
  int64_t peak_active_blocks_ = 0;
  int64_t streamed_out_ = 0;
  int64_t streamed_in_ = 0;
  int64_t last_update_blocks_ = 0;
  int64_t updated_blocks_ = 0;
  std::unique_ptr<HostBlocks> host_;  // blocks streamed out: memory, then disk
  std::unordered_set<BlockCoord, CoordHash> touched_;  // voxels changed since takeMeshChanges()
};

// Raw 16-bit depth (depth_scale units per metre, 0 = none) to CV_32F metres.
cv::Mat depthToMetres(const cv::Mat& raw_depth, double depth_scale);

}  // namespace rekon::volume
