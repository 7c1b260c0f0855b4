#include "rekon/mapper/volume/tsdf_volume.hpp"

#include <fmt/format.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <tuple>

#include "host_blocks.hpp"
#include "marching_cubes.hpp"
#include "rekon/common/error.hpp"

namespace rekon::volume {
namespace {

uint32_t nextPowerOfTwo(uint64_t n) {
  uint64_t p = 1;
  while (p < n) p <<= 1;
  if (p > (1ull << 31)) throw Error("volume: hash table of " + std::to_string(n) + " entries is too large");
  return static_cast<uint32_t>(p);
}

CameraView cameraView(const Intrinsics& k, const Pose& camera_to_world) {
  const Pose world_to_camera = camera_to_world.inverse();
  CameraView c{};
  for (int r = 0; r < 3; ++r) {
    for (int col = 0; col < 3; ++col) c.r[r * 3 + col] = static_cast<float>(world_to_camera.linear()(r, col));
    c.t[r] = static_cast<float>(world_to_camera.translation()(r));
  }
  c.fx = static_cast<float>(k.fx);
  c.fy = static_cast<float>(k.fy);
  c.cx = static_cast<float>(k.cx);
  c.cy = static_cast<float>(k.cy);
  c.width = k.width;
  c.height = k.height;
  return c;
}

void requireImage(const cv::Mat& m, int type, const Intrinsics& k, const char* what, const char* want) {
  if (m.type() != type || m.cols != k.width || m.rows != k.height) {
    throw Error(std::string("volume: ") + what + " image is " + std::to_string(m.cols) + "x" + std::to_string(m.rows) +
                " of type " + std::to_string(m.type()) + "; it must be " + want + " of the intrinsics' size " +
                std::to_string(k.width) + "x" + std::to_string(k.height));
  }
}

bool coordLess(const BlockCoord& a, const BlockCoord& b) { return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z); }

}  // namespace

void VolumeParams::validate() const {
  auto bad = [](const std::string& key, double value, const std::string& want) {
    throw Error("volume." + key + " = " + std::to_string(value) + " is invalid; it must be " + want);
  };
  if (!(voxel_size > 0.0 && voxel_size <= 1.0)) bad("voxel_size", voxel_size, "in (0, 1] metres");
  if (!(truncation >= voxel_size && truncation <= 1.0)) bad("truncation", truncation, "in [voxel_size, 1] metres");
  if (!(max_depth > 0.0)) bad("max_depth", max_depth, "positive (metres)");
  if (block_capacity < 1 || block_capacity > (1 << 28)) bad("block_capacity", block_capacity, "in [1, 2^28]");
  if (!(streaming_radius >= 0.0)) bad("streaming_radius", streaming_radius, ">= 0 metres (0 = no streaming)");
  if (active_max_blocks < 0 || active_max_blocks > (1 << 28)) bad("active_max_blocks", static_cast<double>(active_max_blocks), "in [0, 2^28] (0 = no budget)");
  if (host_max_blocks < 0) bad("host_max_blocks", static_cast<double>(host_max_blocks), ">= 0 (0 = no budget)");
  if (!(weight_units >= 1.0 && weight_units <= 4096.0)) bad("weight_units", weight_units, "in [1, 4096]");
  if (allocation_stride < 1 || allocation_stride > 16) bad("allocation_stride", allocation_stride, "in [1, 16]");
  if (cpu_threads < 0) bad("cpu_threads", cpu_threads, ">= 0 (0 = all)");
}

TsdfVolume::TsdfVolume(const VolumeParams& params) : params_(params) {
  params_.validate();
  host_ = std::make_unique<HostBlocks>(params_.voxel_size, params_.host_max_blocks, params_.spill_dir);
  backend_ = makeBackend(params_.backend, params_.cpu_threads);
  backend_name_ = backend_->name();
  backend_->resizePool(params_.block_capacity);
  slot_coord_.resize(params_.block_capacity);
  slot_used_.assign(params_.block_capacity, 0);
  slot_stamp_.assign(params_.block_capacity, 0);
  for (int32_t s = params_.block_capacity - 1; s >= 0; --s) free_slots_.push_back(s);
  rehash(nextPowerOfTwo(2ull * params_.block_capacity));
}

TsdfVolume::~TsdfVolume() = default;

void TsdfVolume::integrate(const cv::Mat& depth_m, const cv::Mat& color, const cv::Mat& weights, const Intrinsics& k,
                           const Pose& camera_to_world) {
  update(depth_m, color, weights, k, camera_to_world, +1);
}

void TsdfVolume::deintegrate(const cv::Mat& depth_m, const cv::Mat& color, const cv::Mat& weights, const Intrinsics& k,
                             const Pose& camera_to_world) {
  update(depth_m, color, weights, k, camera_to_world, -1);
}

void TsdfVolume::update(const cv::Mat& depth_m, const cv::Mat& color, const cv::Mat& weights, const Intrinsics& k,
                        const Pose& camera_to_world, int sign) {
  const char* what = sign > 0 ? "integrate" : "deintegrate";
  requireValidPose(camera_to_world, std::string("volume ") + what + " camera_to_world");
  k.validate(std::string("volume ") + what);
  requireImage(depth_m, CV_32FC1, k, "depth", "CV_32F metres (convert raw depth with depthToMetres)");
  if (!color.empty()) requireImage(color, CV_8UC3, k, "color", "CV_8UC3 BGR (or empty)");
  if (!weights.empty()) {
    requireImage(weights, CV_32FC1, k, "weights", "CV_32F (or empty for weight 1)");
    // checkRange catches NaN and infinity; a clamp would break exactness silently.
    double lowest = 0.0, highest = 0.0;
    cv::minMaxLoc(weights, &lowest, &highest);
    const double limit = kMaxVoxelWeight / params_.weight_units;
    if (!cv::checkRange(weights) || !(lowest >= 0.0 && highest <= limit)) {
      throw Error("volume: pixel weights must be finite and in [0, " + std::to_string(limit) + "] (found " +
                  std::to_string(lowest) + " .. " + std::to_string(highest) + "); rescale them or lower volume.weight_units");
    }
  }
  const cv::Mat depth_c = depth_m.isContinuous() ? depth_m : depth_m.clone();
  const cv::Mat color_c = color.empty() || color.isContinuous() ? color : color.clone();
  const cv::Mat weights_c = weights.empty() || weights.isContinuous() ? weights : weights.clone();

  const FrameImages frame{depth_c.ptr<float>(), color_c.empty() ? nullptr : color_c.ptr<uint8_t>(),
                          weights_c.empty() ? nullptr : weights_c.ptr<float>(), k.width, k.height};
  const CameraView cam = cameraView(k, camera_to_world);
  const IntegrationSettings settings{static_cast<float>(params_.voxel_size), static_cast<float>(params_.truncation),
                                     static_cast<float>(params_.max_depth), static_cast<float>(params_.weight_units),
                                     static_cast<float>(1.0 / params_.truncation)};
  backend_->setFrame(frame);
  std::vector<BlockCoord> candidates;
  backend_->collectBandBlocks(cam, settings, params_.allocation_stride, candidates);
  size_t fresh_begin = 0;
  const std::vector<BlockRef> blocks = resolveBandBlocks(candidates, sign > 0, &fresh_begin);
  std::vector<uint8_t> empty;
  const FrameUpdateReport report = backend_->updateBlocks(cam, settings, blocks, sign, empty);
  last_update_blocks_ = static_cast<int64_t>(blocks.size());
  updated_blocks_ += last_update_blocks_;
  // Integration frees fresh blocks it did not touch; de-integration every block left without weight.
  for (size_t i = 0; i < blocks.size(); ++i) {
    const bool fresh = sign > 0 && i >= fresh_begin;
    const bool freed = empty[i] && (fresh || sign < 0);
    if (freed) releaseSlot(blocks[i].slot);
    // Integration changed a block's voxels when it updated one (a fresh block freed at once never had a mesh).
    if (sign < 0 || !empty[i]) touched_.insert(blocks[i].coord);
  }
  if (report.weight_overflow) {
    throw Error("volume: a voxel weight exceeded " + std::to_string(kMaxVoxelWeight) +
                " units; lower volume.weight_units (now " + std::to_string(params_.weight_units) +
                ") or the per-pixel weights");
  }
  if (report.weight_underflow) {
    spdlog::error("volume: deintegrate removed more weight than a voxel holds (those voxels were left unchanged); "
                  "de-integrate only frames integrated before, with the same depth, weights and pose");
  }
}

std::vector<BlockRef> TsdfVolume::resolveBandBlocks(const std::vector<BlockCoord>& candidates, bool allocate,
                                                    size_t* fresh_begin) {
  if (++frame_stamp_ == 0) {
    std::fill(slot_stamp_.begin(), slot_stamp_.end(), 0);
    frame_stamp_ = 1;
  }
  std::vector<BlockRef> blocks;
  std::vector<BlockCoord> missing;
  for (const BlockCoord& c : candidates) {
    const int32_t slot = tableFind(c);
    if (slot == kEmptySlot) {
      missing.push_back(c);
    } else if (slot_stamp_[slot] != frame_stamp_) {
      slot_stamp_[slot] = frame_stamp_;
      blocks.push_back({c, slot});
    }
  }
  std::sort(missing.begin(), missing.end(), coordLess);
  missing.erase(std::unique(missing.begin(), missing.end()), missing.end());
  // Blocks of this band that were streamed out come back first: the frame's
  // contribution to them must be added (or removed) like anywhere else.
  std::vector<BlockCoord> stored, fresh;
  for (const BlockCoord& c : missing) (host_->contains(c) ? stored : fresh).push_back(c);
  if (!allocate) fresh.clear();
  // An update away from the streaming centre (a correction round's) brings
  // in only these blocks; with a budget they take the room of the least
  // recently updated ones outside the sphere, never of this band's.
  makeRoom(static_cast<int64_t>(stored.size() + fresh.size()));
  ensureCapacity(active_blocks_ + static_cast<int64_t>(stored.size() + fresh.size()));
  std::vector<int32_t> slots;
  streamIn(stored, slots);
  std::vector<int32_t> fresh_slots;
  for (const BlockCoord& c : fresh) fresh_slots.push_back(takeSlot(c));
  backend_->writeBlocks(fresh_slots, nullptr);
  for (size_t i = 0; i < stored.size(); ++i) blocks.push_back({stored[i], slots[i]});
  *fresh_begin = blocks.size();
  for (size_t i = 0; i < fresh.size(); ++i) blocks.push_back({fresh[i], fresh_slots[i]});
  for (size_t i = 0; i < stored.size() + fresh.size(); ++i) slot_stamp_[blocks[blocks.size() - 1 - i].slot] = frame_stamp_;
  return blocks;
}

void TsdfVolume::ensureCapacity(int64_t active_needed) {
  const int64_t capacity = static_cast<int64_t>(slot_used_.size());
  if (active_needed <= capacity) return;
  if (!params_.grow_capacity) {
    throw Error("volume: " + std::to_string(active_needed) + " active blocks are needed but volume.block_capacity is " +
                std::to_string(capacity) + "; raise block_capacity to at least " + std::to_string(active_needed) +
                " (or set grow_capacity, or lower streaming_radius)");
  }
  // Doubling, but not past the active budget when the pool is below it.
  const int64_t budget = params_.active_max_blocks;
  const int64_t doubled = budget > capacity ? std::min(2 * capacity, budget) : 2 * capacity;
  const int64_t grown = std::max<int64_t>(active_needed, doubled);
  if (grown > (1 << 28)) {
    throw Error("volume: " + std::to_string(active_needed) + " active blocks exceed the limit of 2^28; lower streaming_radius");
  }
  spdlog::info("volume: growing the active pool from {} to {} blocks ({} MiB)", capacity, grown,
               grown * kBlockVoxels * sizeof(Voxel) >> 20);
  backend_->resizePool(static_cast<int32_t>(grown));
  slot_coord_.resize(grown);
  slot_used_.resize(grown, 0);
  slot_stamp_.resize(grown, 0);
  std::vector<int32_t> added;
  for (int64_t s = grown - 1; s >= capacity; --s) added.push_back(static_cast<int32_t>(s));
  free_slots_.insert(free_slots_.begin(), added.begin(), added.end());
  rehash(nextPowerOfTwo(2ull * grown));
}

int32_t TsdfVolume::takeSlot(const BlockCoord& coord) {
  if (free_slots_.empty()) throw Error("volume: internal error: no free slot after ensureCapacity");
  const int32_t slot = free_slots_.back();
  free_slots_.pop_back();
  slot_used_[slot] = 1;
  slot_coord_[slot] = coord;
  tableInsert(coord, slot);
  peak_active_blocks_ = std::max(peak_active_blocks_, ++active_blocks_);
  return slot;
}

void TsdfVolume::releaseSlot(int32_t slot) {
  tableErase(slot_coord_[slot]);
  slot_used_[slot] = 0;
  free_slots_.push_back(slot);
  --active_blocks_;
}

void TsdfVolume::rehash(uint32_t table_size) {
  table_.assign(table_size, HashEntry{{0, 0, 0}, kEmptySlot});
  for (size_t s = 0; s < slot_used_.size(); ++s) {
    if (slot_used_[s]) tableInsert(slot_coord_[s], static_cast<int32_t>(s));
  }
  ++table_version_;
}

void TsdfVolume::tableInsert(const BlockCoord& coord, int32_t slot) {
  const uint32_t mask = static_cast<uint32_t>(table_.size() - 1);
  uint32_t i = hashBlock(coord) & mask;
  while (table_[i].slot != kEmptySlot) i = (i + 1) & mask;
  table_[i] = {coord, slot};
  ++table_version_;
}

int32_t TsdfVolume::tableFind(const BlockCoord& coord) const {
  return findBlock(HashView{table_.data(), static_cast<uint32_t>(table_.size() - 1)}, coord);
}

// Backward-shift deletion keeps linear probing free of tombstones.
void TsdfVolume::tableErase(const BlockCoord& coord) {
  const uint32_t mask = static_cast<uint32_t>(table_.size() - 1);
  uint32_t i = hashBlock(coord) & mask;
  while (!(table_[i].slot != kEmptySlot && table_[i].coord == coord)) {
    if (table_[i].slot == kEmptySlot) return;
    i = (i + 1) & mask;
  }
  uint32_t j = i;
  while (true) {
    j = (j + 1) & mask;
    if (table_[j].slot == kEmptySlot) break;
    const uint32_t home = hashBlock(table_[j].coord) & mask;
    // Move j back to the hole at i unless its home lies cyclically in (i, j].
    const bool home_between = (i <= j) ? (home > i && home <= j) : (home > i || home <= j);
    if (!home_between) {
      table_[i] = table_[j];
      i = j;
    }
  }
  table_[i].slot = kEmptySlot;
  ++table_version_;
}

void TsdfVolume::streamIn(const std::vector<BlockCoord>& coords, std::vector<int32_t>& slots) {
  slots.clear();
  if (coords.empty()) return;
  ensureCapacity(active_blocks_ + static_cast<int64_t>(coords.size()));
  std::vector<Voxel> data(coords.size() * kBlockVoxels);
  for (size_t i = 0; i < coords.size(); ++i) {
    host_->take(coords[i], data.data() + i * kBlockVoxels);
    slots.push_back(takeSlot(coords[i]));
    slot_stamp_[slots.back()] = frame_stamp_;  // used now: not the first to leave again
  }
  backend_->writeBlocks(slots, data.data());
  streamed_in_ += static_cast<int64_t>(coords.size());
}

void TsdfVolume::streamAround(const Eigen::Vector3d& centre) {
  if (!centre.allFinite()) throw Error("volume: streaming centre is not finite; pass the camera position");
  if (params_.streaming_radius <= 0.0) return;
  const double r = params_.streaming_radius;
  const std::vector<BlockCoord> in_coords = host_->within(centre, r);
  streaming_centre_ = centre;
  if (params_.active_max_blocks == 0) streamOutBeyond(centre, 0);
  makeRoom(static_cast<int64_t>(in_coords.size()));
  std::vector<int32_t> slots;
  streamIn(in_coords, slots);
  host_->spillBeyondBudget(centre);
}

void TsdfVolume::makeRoom(int64_t incoming) {
  if (params_.active_max_blocks == 0 || params_.streaming_radius <= 0.0) return;
  // A sixteenth of the budget is left free for the blocks the next
  // integrations allocate. Once that share is taken, blocks leave in a batch
  // of another sixteenth, so that the pool is searched for the blocks to
  // leave once per batch rather than before every (de-)integration.
  const int64_t share = params_.active_max_blocks / 16;
  const int64_t excess = active_blocks_ + incoming - (params_.active_max_blocks - share);
  if (excess <= 0) return;
  streamOutBeyond(streaming_centre_, excess + share);
  host_->spillBeyondBudget(streaming_centre_);
}

void TsdfVolume::streamOutBeyond(const Eigen::Vector3d& centre, int64_t excess) {
  // Without a budget every block outside the sphere leaves; with one, only the
  // excess, least recently updated first (then farthest): a round's blocks stay
  // for the next round, the camera's for the next integration.
  struct Candidate {
    uint32_t last_use;
    double distance;
    int32_t slot;
  };
  std::vector<Candidate> outside;
  const bool budget = params_.active_max_blocks > 0;
  for (size_t s = 0; s < slot_used_.size(); ++s) {
    if (!slot_used_[s] || (budget && slot_stamp_[s] == frame_stamp_)) continue;  // the latest update's blocks stay
    const double d = (blockCentre(slot_coord_[s], params_.voxel_size) - centre).norm();
    if (d > params_.streaming_radius) outside.push_back({slot_stamp_[s], d, static_cast<int32_t>(s)});
  }
  size_t n = outside.size();
  if (budget) {
    n = std::min(n, static_cast<size_t>(std::max<int64_t>(0, excess)));
    std::nth_element(outside.begin(), outside.begin() + static_cast<std::ptrdiff_t>(n), outside.end(),
                     [](const Candidate& a, const Candidate& b) {
                       return a.last_use < b.last_use || (a.last_use == b.last_use && a.distance > b.distance);
                     });
  }
  if (n == 0) return;
  std::vector<int32_t> out_slots;
  for (size_t i = 0; i < n; ++i) out_slots.push_back(outside[i].slot);
  std::vector<Voxel> data(out_slots.size() * kBlockVoxels);
  backend_->readBlocks(out_slots, data.data());
  for (size_t i = 0; i < out_slots.size(); ++i) {
    host_->insert(slot_coord_[out_slots[i]], data.data() + i * kBlockVoxels);
    releaseSlot(out_slots[i]);
  }
  streamed_out_ += static_cast<int64_t>(out_slots.size());
}

Mesh TsdfVolume::extractMesh() const {
  Mesh mesh;
  extractMeshInPieces([&mesh](const Mesh& piece) { appendMesh(mesh, piece); });
  return mesh;
}

void TsdfVolume::extractMeshInPieces(const std::function<void(const Mesh&)>& sink, int blocks_per_piece) const {
  std::vector<BlockCoord> coords = blockCoords();
  std::sort(coords.begin(), coords.end(), [](const BlockCoord& a, const BlockCoord& b) {
    return std::tie(a.x, a.y, a.z) > std::tie(b.x, b.y, b.z);  // MeshPieces' order
  });
  MeshPieces pieces(static_cast<float>(params_.voxel_size), static_cast<float>(params_.truncation));
  for (size_t begin = 0; begin < coords.size(); begin += static_cast<size_t>(blocks_per_piece)) {
    const size_t end = std::min(coords.size(), begin + static_cast<size_t>(blocks_per_piece));
    const std::vector<BlockCoord> piece = withUpperNeighbours(
        {coords.begin() + static_cast<std::ptrdiff_t>(begin), coords.begin() + static_cast<std::ptrdiff_t>(end)});
    std::vector<const Voxel*> data;
    std::vector<Voxel> copied;  // this piece's blocks read from disk (or the device) only
    voxelPointers(piece, data, copied);
    sink(pieces.next(piece, data, static_cast<int>(end - begin)));
  }
}

std::vector<BlockCoord> TsdfVolume::takeMeshChanges() {
  std::unordered_set<BlockCoord, CoordHash> changed;
  for (const BlockCoord& c : touched_) {
    for (int n = 0; n < 8; ++n) changed.insert({c.x - (n & 1), c.y - ((n >> 1) & 1), c.z - ((n >> 2) & 1)});
  }
  std::vector<BlockCoord> out;
  out.reserve(changed.size());
  for (const BlockCoord& c : changed) {
    // A neighbour that does not exist has no mesh to change, unless it was freed (then it was touched itself).
    if (exists(c) || touched_.count(c)) out.push_back(c);
  }
  touched_.clear();
  return out;
}

std::vector<BlockCoord> TsdfVolume::withUpperNeighbours(std::vector<BlockCoord> blocks) const {
  std::unordered_set<BlockCoord, CoordHash> listed(blocks.begin(), blocks.end());
  const size_t n = blocks.size();
  for (size_t i = 0; i < n; ++i) {
    for (int k = 1; k < 8; ++k) {
      const BlockCoord nb{blocks[i].x + (k & 1), blocks[i].y + ((k >> 1) & 1), blocks[i].z + ((k >> 2) & 1)};
      if (exists(nb) && listed.insert(nb).second) blocks.push_back(nb);
    }
  }
  return blocks;
}

bool TsdfVolume::exists(const BlockCoord& c) const { return tableFind(c) != kEmptySlot || host_->contains(c); }

std::vector<BlockMesh> TsdfVolume::meshBlocks(const std::vector<BlockCoord>& wanted, int max_workers) const {
  std::vector<BlockCoord> present;
  std::unordered_set<BlockCoord, CoordHash> listed;
  for (const BlockCoord& c : wanted) {
    if (exists(c) && listed.insert(c).second) present.push_back(c);
  }
  const int count = static_cast<int>(present.size());
  const std::vector<BlockCoord> coords = withUpperNeighbours(std::move(present));
  std::vector<const Voxel*> data;
  std::vector<Voxel> copied;
  voxelPointers(coords, data, copied);
  std::vector<BlockMesh> meshes = marchingCubesPerBlock(coords, data, count, static_cast<float>(params_.voxel_size),
                                                        static_cast<float>(params_.truncation), max_workers);
  for (const BlockCoord& c : wanted) {
    if (!listed.count(c)) meshes.push_back(BlockMesh{c.x, c.y, c.z, 0, {}, {}, {}});
  }
  return meshes;
}

void TsdfVolume::voxelPointers(const std::vector<BlockCoord>& coords, std::vector<const Voxel*>& data,
                               std::vector<Voxel>& copied) const {
  // Copies (of active blocks when the pool is not on the host, of host blocks
  // on disk) go to `copied`, sized once so that the pointers into it hold.
  const Voxel* pool = backend_->hostPool();
  std::vector<int32_t> slots;
  size_t from_disk = 0;
  for (const BlockCoord& c : coords) {
    const int32_t slot = tableFind(c);
    if (slot != kEmptySlot) slots.push_back(slot);
    else if (!host_->inMemory(c)) ++from_disk;
  }
  const size_t active_copies = pool == nullptr ? slots.size() : 0;
  copied.resize((active_copies + from_disk) * kBlockVoxels);
  if (active_copies > 0) backend_->readBlocks(slots, copied.data());
  size_t active = 0, disk = active_copies;
  data.reserve(data.size() + coords.size());
  for (const BlockCoord& c : coords) {
    const int32_t slot = tableFind(c);
    if (slot != kEmptySlot) {
      data.push_back(pool ? pool + static_cast<size_t>(slot) * kBlockVoxels : copied.data() + active * kBlockVoxels);
      ++active;
    } else if (const Voxel* v = host_->inMemory(c)) {
      data.push_back(v);
    } else {
      Voxel* dst = copied.data() + disk++ * kBlockVoxels;
      if (!host_->read(c, dst)) throw Error("volume: internal error: block listed but not allocated");
      data.push_back(dst);
    }
  }
}

RaycastImages TsdfVolume::raycast(const Intrinsics& k, const Pose& camera_to_world) const {
  requireValidPose(camera_to_world, "volume raycast camera_to_world");
  k.validate("volume raycast");
  const CameraView cam = cameraView(k, camera_to_world);
  // Depth range per tile from the projections of the active blocks' corners.
  constexpr int kTile = 8;
  const int tiles_x = (k.width + kTile - 1) / kTile, tiles_y = (k.height + kTile - 1) / kTile;
  std::vector<float> near(tiles_x * tiles_y, std::numeric_limits<float>::max()), far(tiles_x * tiles_y, 0.f);
  const float side = static_cast<float>(kBlockSide * params_.voxel_size);
  for (size_t s = 0; s < slot_used_.size(); ++s) {
    if (!slot_used_[s]) continue;
    const BlockCoord& c = slot_coord_[s];
    float z_min = std::numeric_limits<float>::max(), z_max = 0.f, u_min = 1e9f, u_max = -1e9f, v_min = 1e9f, v_max = -1e9f;
    bool behind = false;
    for (int corner = 0; corner < 8; ++corner) {
      const Vec3f p = worldToCamera(cam, {(c.x + (corner & 1)) * side, (c.y + ((corner >> 1) & 1)) * side,
                                          (c.z + ((corner >> 2) & 1)) * side});
      z_min = std::min(z_min, p.z);
      z_max = std::max(z_max, p.z);
      if (p.z <= 1e-3f) {
        behind = true;
        continue;
      }
      const float u = cam.fx * p.x / p.z + cam.cx, v = cam.fy * p.y / p.z + cam.cy;
      u_min = std::min(u_min, u);
      u_max = std::max(u_max, u);
      v_min = std::min(v_min, v);
      v_max = std::max(v_max, v);
    }
    if (z_max <= 1e-3f) continue;  // wholly behind the camera
    if (behind) {                   // straddles the camera plane: may cover any pixel
      u_min = v_min = -1e9f;
      u_max = v_max = 1e9f;
      z_min = 0.f;
    }
    const int tx0 = std::max(0, static_cast<int>(std::floor(u_min)) / kTile);
    const int tx1 = std::min(tiles_x - 1, static_cast<int>(std::min(u_max, 1e8f)) / kTile);
    const int ty0 = std::max(0, static_cast<int>(std::floor(v_min)) / kTile);
    const int ty1 = std::min(tiles_y - 1, static_cast<int>(std::min(v_max, 1e8f)) / kTile);
    if (u_max < 0.f || v_max < 0.f) continue;
    for (int ty = ty0; ty <= ty1; ++ty) {
      for (int tx = tx0; tx <= tx1; ++tx) {
        near[ty * tiles_x + tx] = std::min(near[ty * tiles_x + tx], z_min);
        far[ty * tiles_x + tx] = std::max(far[ty * tiles_x + tx], z_max);
      }
    }
  }
  const TileDepthRanges ranges{near.data(), far.data(), tiles_x, kTile};
  std::vector<RaycastPixel> pixels(static_cast<size_t>(k.width) * k.height);
  backend_->raycast(table_, table_version_, cam, ranges, tiles_x * tiles_y, static_cast<float>(params_.voxel_size),
                    static_cast<float>(params_.truncation), static_cast<float>(params_.max_depth), pixels.data());
  RaycastImages out;
  out.depth.create(k.height, k.width, CV_32FC1);
  out.normals.create(k.height, k.width, CV_32FC3);
  out.color.create(k.height, k.width, CV_8UC3);
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) {
      const RaycastPixel& p = pixels[static_cast<size_t>(v) * k.width + u];
      out.depth.at<float>(v, u) = p.depth;
      out.normals.at<cv::Vec3f>(v, u) = {p.normal.x, p.normal.y, p.normal.z};
      out.color.at<cv::Vec3b>(v, u) = {p.b, p.g, p.r};
    }
  }
  return out;
}

VolumeStats TsdfVolume::stats() const {
  VolumeStats s;
  s.active_blocks = active_blocks_;
  s.host_blocks = host_->size();
  const HostTierStats h = host_->stats();
  s.host_blocks_on_disk = h.on_disk;
  s.spilled_to_disk = h.spilled;
  s.read_back_from_disk = h.read_back;
  s.blocks = s.active_blocks + s.host_blocks;
  s.peak_active_blocks = peak_active_blocks_;
  s.block_capacity = static_cast<int64_t>(slot_used_.size());
  s.streamed_out = streamed_out_;
  s.streamed_in = streamed_in_;
  s.last_update_blocks = last_update_blocks_;
  s.updated_blocks = updated_blocks_;
  s.backend = backend_name_;
  return s;
}

bool TsdfVolume::readBlock(const BlockCoord& coord, std::vector<Voxel>& voxels) const {
  const int32_t slot = tableFind(coord);
  if (slot != kEmptySlot) {
    voxels.resize(kBlockVoxels);
    backend_->readBlocks({slot}, voxels.data());
    return true;
  }
  voxels.resize(kBlockVoxels);
  return host_->read(coord, voxels.data());
}

std::vector<BlockCoord> TsdfVolume::blockCoords() const {
  std::vector<BlockCoord> out;
  for (size_t s = 0; s < slot_used_.size(); ++s) {
    if (slot_used_[s]) out.push_back(slot_coord_[s]);
  }
  const std::vector<BlockCoord> host = host_->coords();
  out.insert(out.end(), host.begin(), host.end());
  return out;
}

cv::Mat depthToMetres(const cv::Mat& raw_depth, double depth_scale) {
  if (raw_depth.type() != CV_16UC1) {
    throw Error("depthToMetres: depth image has type " + std::to_string(raw_depth.type()) +
                "; it must be 16-bit single-channel (CV_16UC1)");
  }
  if (!(std::isfinite(depth_scale) && depth_scale > 0.0)) {
    throw Error("depthToMetres: depth_scale " + fmt::format("{}", depth_scale) + " must be positive (units per metre)");
  }
  cv::Mat metres;
  raw_depth.convertTo(metres, CV_32FC1, 1.0 / depth_scale);
  return metres;
}

}  // namespace rekon::volume
