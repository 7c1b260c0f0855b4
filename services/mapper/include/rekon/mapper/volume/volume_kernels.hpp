#pragma once
// The per-voxel and per-pixel maths of the TSDF volume, written once and
// called from the CPU backend's loops and from the CUDA kernels in cuda/.
// Plain structs only (no Eigen, no STL) so nvcc compiles it without flags.
#include <cmath>
#include <cstdint>

#ifdef __CUDACC__
#define REKON_HD __host__ __device__
#else
#define REKON_HD
#endif

namespace rekon::volume {

constexpr int kBlockSide = 8;  // voxels per block edge (Voxel Hashing's 8^3 blocks)
constexpr int kBlockVoxels = kBlockSide * kBlockSide * kBlockSide;

// The truncated signed distance tsdf in [-1, 1] (units of the truncation
// distance) is quantised to integer steps of 1/kSdfSteps. Storing weighted
// *sums* of integers, not averages, makes de-integration (paper eq. 2) exact
// and independent of order: subtraction undoes addition bit for bit.
constexpr int32_t kSdfSteps = 1023;
// |sdf_sum| <= weight * kSdfSteps must fit in int32, so the weight has 21
// bits; exceeding it is reported as an error, never clamped silently.
constexpr int kWeightBits = 21;
constexpr uint32_t kMaxVoxelWeight = (1u << kWeightBits) - 1;
// Color is a weighted running average kept with 6 fractional bits (14 bits per
// channel). Eq. 2's de-integration divides by the remaining weight and so
// magnifies the stored rounding by (weight before / weight after); 1/64 of a
// level keeps that below one 8-bit level for up to ~30x weight reductions.
constexpr int kColorBits = 14;
constexpr uint32_t kColorScale = 64;  // fixed-point units per 8-bit level
constexpr uint32_t kMaxColor = 255 * kColorScale;

// 12 bytes: the signed-distance sum, then weight and r, g, b packed into 64
// bits (weight in bits 0-20, r 21-34, g 35-48, b 49-62).
struct Voxel {
  int32_t sdf_sum;   // sum of weight_units * round(tsdf * kSdfSteps)
  uint32_t bits[2];  // see voxelWeight / voxelColor
};
static_assert(sizeof(Voxel) == 12, "the voxel layout is part of the memory budget");

REKON_HD inline uint64_t packedBits(const Voxel& v) {
  return static_cast<uint64_t>(v.bits[0]) | (static_cast<uint64_t>(v.bits[1]) << 32);
}
// Sum of weight units; 0 = unobserved.
REKON_HD inline uint32_t voxelWeight(const Voxel& v) { return v.bits[0] & kMaxVoxelWeight; }
// Fixed-point average of channel 0 = red, 1 = green, 2 = blue.
REKON_HD inline uint32_t voxelColorFixed(const Voxel& v, int channel) {
  return static_cast<uint32_t>(packedBits(v) >> (kWeightBits + kColorBits * channel)) & ((1u << kColorBits) - 1);
}
REKON_HD inline uint8_t voxelColor(const Voxel& v, int channel) {
  return static_cast<uint8_t>((voxelColorFixed(v, channel) + kColorScale / 2) / kColorScale);
}
REKON_HD inline void setWeightAndColor(Voxel& v, uint32_t weight, uint32_t r, uint32_t g, uint32_t b) {
  const uint64_t p = static_cast<uint64_t>(weight) | (static_cast<uint64_t>(r) << kWeightBits) |
                     (static_cast<uint64_t>(g) << (kWeightBits + kColorBits)) |
                     (static_cast<uint64_t>(b) << (kWeightBits + 2 * kColorBits));
  v.bits[0] = static_cast<uint32_t>(p);
  v.bits[1] = static_cast<uint32_t>(p >> 32);
}

struct Vec3f {
  float x, y, z;
};
REKON_HD inline Vec3f operator+(Vec3f a, Vec3f b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
REKON_HD inline Vec3f operator-(Vec3f a, Vec3f b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
REKON_HD inline Vec3f operator*(float s, Vec3f a) { return {s * a.x, s * a.y, s * a.z}; }
REKON_HD inline float dot(Vec3f a, Vec3f b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

struct BlockCoord {
  int32_t x, y, z;
};
REKON_HD inline bool operator==(BlockCoord a, BlockCoord b) { return a.x == b.x && a.y == b.y && a.z == b.z; }

// Spatial hash of Teschner et al., as in Voxel Hashing.
REKON_HD inline uint32_t hashBlock(BlockCoord c) {
  return (static_cast<uint32_t>(c.x) * 73856093u) ^ (static_cast<uint32_t>(c.y) * 19349669u) ^
         (static_cast<uint32_t>(c.z) * 83492791u);
}

// Open-addressing (linear probing) table from block coordinate to pool slot.
// The host owns and edits it; kernels only look up.
struct HashEntry {
  BlockCoord coord;
  int32_t slot;  // kEmptySlot when the entry is free
};
constexpr int32_t kEmptySlot = -1;

struct HashView {
  const HashEntry* entries;
  uint32_t mask;  // table size - 1 (a power of two)
};

REKON_HD inline int32_t findBlock(HashView table, BlockCoord c) {
  uint32_t i = hashBlock(c) & table.mask;
  while (true) {
    const HashEntry& e = table.entries[i];
    if (e.slot == kEmptySlot) return kEmptySlot;
    if (e.coord == c) return e.slot;
    i = (i + 1) & table.mask;
  }
}

REKON_HD inline int floorDiv(int a, int b) { return (a >= 0) ? a / b : -((-a + b - 1) / b); }
REKON_HD inline int localIndex(int x, int y, int z) { return (z * kBlockSide + y) * kBlockSide + x; }

// A pinhole camera at a pose, in float: world-to-camera rotation (row-major)
// and translation plus intrinsics.
struct CameraView {
  float r[9];
  float t[3];
  float fx, fy, cx, cy;
  int width, height;
};

REKON_HD inline Vec3f worldToCamera(const CameraView& c, Vec3f p) {
  return {c.r[0] * p.x + c.r[1] * p.y + c.r[2] * p.z + c.t[0], c.r[3] * p.x + c.r[4] * p.y + c.r[5] * p.z + c.t[1],
          c.r[6] * p.x + c.r[7] * p.y + c.r[8] * p.z + c.t[2]};
}
// Inverse of worldToCamera (R^T (p - t)).
REKON_HD inline Vec3f cameraToWorld(const CameraView& c, Vec3f p) {
  const Vec3f q = p - Vec3f{c.t[0], c.t[1], c.t[2]};
  return {c.r[0] * q.x + c.r[3] * q.y + c.r[6] * q.z, c.r[1] * q.x + c.r[4] * q.y + c.r[7] * q.z,
          c.r[2] * q.x + c.r[5] * q.y + c.r[8] * q.z};
}
REKON_HD inline Vec3f cameraCentre(const CameraView& c) { return cameraToWorld(c, {0.f, 0.f, 0.f}); }
REKON_HD inline Vec3f cameraDirectionToWorld(const CameraView& c, Vec3f d) {
  return {c.r[0] * d.x + c.r[3] * d.y + c.r[6] * d.z, c.r[1] * d.x + c.r[4] * d.y + c.r[7] * d.z,
          c.r[2] * d.x + c.r[5] * d.y + c.r[8] * d.z};
}

// The inputs of one (de-)integration, as device or host pointers to dense rows.
struct FrameImages {
  const float* depth;    // metres, 0 or non-finite = no measurement
  const uint8_t* bgr;    // may be null: color is then left unchanged
  const float* weights;  // may be null: every pixel weighs 1
  int width, height;
};

struct IntegrationSettings {
  float voxel_size;
  float truncation;
  float max_depth;
  float weight_units;  // integer weight units per unit of pixel weight
  float inv_truncation;
};

REKON_HD inline bool validDepth(float z, float max_depth) { return z > 0.f && z <= max_depth; }  // false for NaN

// kWeighted says whether the frame has a weight image (without one every pixel
// weighs 1). A template parameter rather than a test of the pointer per voxel,
// so that the row loop of updateBlock has no branch and vectorises.
template <bool kWeighted>
REKON_HD inline uint32_t pixelWeightUnits(const float* weights, int pixel, float weight_units) {
  if constexpr (!kWeighted) {
    return static_cast<uint32_t>(weight_units + 0.5f);
  } else {
    const float w = weights[pixel];
    // Clamped before the conversion, not after: converting a float out of
    // int32's range is undefined, and SIMD converts to signed integers only.
    const float units = w > 0.f ? w * weight_units + 0.5f : 0.f;  // 0 for NaN too
    const float max_units = static_cast<float>(kMaxVoxelWeight);     // exact: below 2^24
    return static_cast<uint32_t>(static_cast<int32_t>(units < max_units ? units : max_units));
  }
}
REKON_HD inline uint32_t pixelWeightUnits(const FrameImages& f, int pixel, float weight_units) {
  return f.weights ? pixelWeightUnits<true>(f.weights, pixel, weight_units)
                   : pixelWeightUnits<false>(nullptr, pixel, weight_units);
}

// What one frame says about one voxel. `weight == 0` means nothing.
struct Observation {
  int32_t sdf;      // round(tsdf * kSdfSteps)
  uint32_t weight;  // weight units
  int pixel;        // for the color; -1 without color
};

// x clamped to [lo, hi]; lo for NaN. Selects that compile to min/max instructions.
REKON_HD inline float clampSelect(float x, float lo, float hi) {
  x = x > lo ? x : lo;
  return x < hi ? x : hi;
}

// Projective (along z) truncated signed distance of the voxel at camera
// coordinates `pc`, as in KinectFusion and the paper's eq. 2. Written without
// early returns: every test becomes a mask, so neighbouring voxels run the
// same instructions (no mispredicted branches on the CPU, no divergence on
// the GPU) and a row of voxels can be computed side by side. Masks combine
// with `&`, not `&&`, and values are clamped rather than selected by a mask
// where a masked-out value is not used: GCC keeps a loop scalar when it would
// have to speculate a float operation out of a branch (it may trap).
template <bool kWeighted>
REKON_HD inline Observation observe(const FrameImages& f, const CameraView& cam, const IntegrationSettings& s, Vec3f pc) {
  const float inv_z = 1.f / pc.z;
  const float uf = cam.fx * pc.x * inv_z + cam.cx;
  const float vf = cam.fy * pc.y * inv_z + cam.cy;
  // False for NaN too (pc.z = 0 gives inf * 0).
  const bool inside = (pc.z > 0.f) & (uf > -0.5f) & (vf > -0.5f) & (uf < cam.width - 0.5f) & (vf < cam.height - 0.5f);
  // The nearest pixel when inside (clamping moves no coordinate that rounds
  // into the image), some pixel of the image otherwise.
  const int u = static_cast<int>(clampSelect(uf, 0.f, static_cast<float>(cam.width - 1)) + 0.5f);
  const int v = static_cast<int>(clampSelect(vf, 0.f, static_cast<float>(cam.height - 1)) + 0.5f);
  const int pixel = v * f.width + u;
  const float depth = f.depth[pixel];
  const float sdf = depth - pc.z;
  const uint32_t w = pixelWeightUnits<kWeighted>(f.weights, pixel, s.weight_units);
  const bool valid = inside & (depth > 0.f) & (depth <= s.max_depth) & (sdf >= -s.truncation) & (w != 0u);
  // Where valid, sdf >= -truncation: clamping at -1 changes no rounded value
  // (and keeps a NaN of an invalid voxel, whose sdf is unused, in range).
  const float q = clampSelect(sdf * s.inv_truncation, -1.f, 1.f) * static_cast<float>(kSdfSteps);
  const float rounded = q >= 0.f ? q + 0.5f : q - 0.5f;
  const bool has_color = f.bgr != nullptr;
  return {static_cast<int32_t>(rounded), valid ? w : 0u, (valid & has_color) ? pixel : -1};
}
REKON_HD inline Observation observe(const FrameImages& f, const CameraView& cam, const IntegrationSettings& s, Vec3f pc) {
  return f.weights ? observe<true>(f, cam, s, pc) : observe<false>(f, cam, s, pc);
}

// One row of a block (x = 0..7) as a frame sees it, as structure of arrays:
// filling it is then one SIMD lane per voxel (the depth read a gather).
struct ObservationRow {
  int32_t sdf[kBlockSide];
  uint32_t weight[kBlockSide];
  int32_t pixel[kBlockSide];
  uint32_t bgr[kBlockSide];  // pixelBgr of `pixel` (of pixel 0 where it is -1)
};

enum UpdateStatus : int { kUpdated = 0, kWeightOverflow = 1, kWeightUnderflow = 2 };

// Weighted running average in fixed point, in the incremental form
// avg + (sample - avg) * w / W_new, which (unlike (avg W + s w) / W_new) does
// not cancel large products when de-integration leaves little weight, so float
// keeps its error far below one fixed-point unit. Clamped before the
// conversion (NaN to 0; the value of a blend that is not applied), through
// int32: what SIMD converts.
REKON_HD inline uint32_t blendColor(uint32_t old_fixed, int sample, float ratio) {
  const float old_value = static_cast<float>(static_cast<int32_t>(old_fixed));
  const float avg = old_value + (static_cast<float>(sample * static_cast<int>(kColorScale)) - old_value) * ratio + 0.5f;
  return static_cast<uint32_t>(static_cast<int32_t>(clampSelect(avg, 0.f, static_cast<float>(kMaxColor))));
}

// `a` where `take`, else `b`, by masks rather than a conditional: GCC turns a
// choice between a new and the stored value into a conditional store, and
// sinks the loads of values used on one side only into a branch, and then
// keeps the loop scalar.
REKON_HD inline uint32_t maskSelect(bool take, uint32_t a, uint32_t b) {
  const uint32_t mask = 0u - static_cast<uint32_t>(take);
  return (a & mask) | (b & ~mask);
}

// A pixel's B, G and R in the low three bytes of a word.
REKON_HD inline uint32_t pixelBgr(const uint8_t* bgr, int pixel) {
  const uint8_t* c = bgr + 3 * pixel;
  return static_cast<uint32_t>(c[0]) | (static_cast<uint32_t>(c[1]) << 8) | (static_cast<uint32_t>(c[2]) << 16);
}

// Adds (sign = +1) or removes (sign = -1) one observation: the weighted running
// average of the paper's integration and its inverse, eq. 2; `bgr` is the
// color of o.pixel (pixelBgr), unused when o.pixel < 0. An observation
// without weight, or one that would overflow or underflow the weight, leaves
// v as it was. Branch-free like observe() (every value computed, then
// selected, v always written), so that a row of voxels updates side by side.
REKON_HD inline int applyObservation(Voxel& v, const Observation& o, uint32_t bgr, int sign) {
  const uint32_t lo = v.bits[0], hi = v.bits[1];  // see setWeightAndColor
  const uint32_t weight = lo & kMaxVoxelWeight;
  const bool adding = sign > 0;
  const bool overflow = adding & (weight > kMaxVoxelWeight - o.weight);
  const bool underflow = !adding & (weight < o.weight);
  const bool apply = (o.weight != 0u) & !overflow & !underflow;
  const int32_t sw = adding ? static_cast<int32_t>(o.weight) : -static_cast<int32_t>(o.weight);
  const uint32_t new_weight = weight + static_cast<uint32_t>(sw);
  constexpr uint32_t kChannel = (1u << kColorBits) - 1;
  const uint32_t r = (lo >> kWeightBits) | ((hi << (32 - kWeightBits)) & kChannel);
  const uint32_t g = (hi >> (kWeightBits + kColorBits - 32)) & kChannel;
  const uint32_t b = (hi >> (kWeightBits + 2 * kColorBits - 32)) & kChannel;
  // Both weights are below 2^21: exact as int32 and as float.
  const float ratio = static_cast<float>(sw) / static_cast<float>(static_cast<int32_t>(new_weight));
  const bool blend = o.pixel >= 0, kept = new_weight != 0u;  // all weight removed: no color
  const uint32_t new_r = maskSelect(kept, maskSelect(blend, blendColor(r, (bgr >> 16) & 0xffu, ratio), r), 0u);
  const uint32_t new_g = maskSelect(kept, maskSelect(blend, blendColor(g, (bgr >> 8) & 0xffu, ratio), g), 0u);
  const uint32_t new_b = maskSelect(kept, maskSelect(blend, blendColor(b, bgr & 0xffu, ratio), b), 0u);
  const int32_t sdf_sum = v.sdf_sum;
  v.sdf_sum = static_cast<int32_t>(
      maskSelect(apply, static_cast<uint32_t>(sdf_sum + sw * o.sdf), static_cast<uint32_t>(sdf_sum)));
  v.bits[0] = maskSelect(apply, new_weight | (new_r << kWeightBits), lo);
  v.bits[1] = maskSelect(apply,
                         (new_r >> (32 - kWeightBits)) | (new_g << (kWeightBits + kColorBits - 32)) |
                             (new_b << (kWeightBits + 2 * kColorBits - 32)),
                         hi);
  return overflow ? kWeightOverflow : (underflow ? kWeightUnderflow : kUpdated);
}

// Camera coordinates of a block's voxels: origin plus integer steps along
// the three voxel axes (one add per voxel instead of a full transform).
struct BlockInCamera {
  Vec3f origin, dx, dy, dz;
};

REKON_HD inline BlockInCamera blockInCamera(const CameraView& cam, BlockCoord coord, float vs) {
  const Vec3f origin{coord.x * kBlockSide * vs, coord.y * kBlockSide * vs, coord.z * kBlockSide * vs};
  return {worldToCamera(cam, origin), {cam.r[0] * vs, cam.r[3] * vs, cam.r[6] * vs},
          {cam.r[1] * vs, cam.r[4] * vs, cam.r[7] * vs}, {cam.r[2] * vs, cam.r[5] * vs, cam.r[8] * vs}};
}
REKON_HD inline Vec3f voxelInCamera(const BlockInCamera& b, int x, int y, int z) {
  return (b.origin + static_cast<float>(y) * b.dy + static_cast<float>(z) * b.dz) + static_cast<float>(x) * b.dx;
}

// Updates one voxel (the body both backends run per voxel); returns an UpdateStatus.
REKON_HD inline int updateVoxel(Voxel& v, const BlockInCamera& b, int x, int y, int z, const FrameImages& f,
                                const CameraView& cam, const IntegrationSettings& s, int sign, bool& observed) {
  const Observation o = observe(f, cam, s, voxelInCamera(b, x, y, z));
  observed = o.weight != 0u;
  return observed ? applyObservation(v, o, o.pixel >= 0 ? pixelBgr(f.bgr, o.pixel) : 0u, sign)
                  : static_cast<int>(kUpdated);
}

// Result of updating one block: which statuses occurred, and `occupied`:
// for integration whether the frame updated any voxel (only then does a
// freshly allocated block hold data), for de-integration whether any voxel
// still carries weight (a block with none is freed). Integration's answer
// thus depends on no voxel it does not update.
struct BlockUpdateResult {
  int overflow;
  int underflow;
  int occupied;
};

REKON_HD inline bool blockOccupiedAfter(const Voxel& v, int status, bool observed, int sign) {
  return sign > 0 ? (observed && status == kUpdated) : voxelWeight(v) != 0u;
}

template <bool kWeighted, bool kColor>
REKON_HD inline BlockUpdateResult updateBlock(Voxel* voxels, BlockCoord coord, const FrameImages& f,
                                              const CameraView& cam, const IntegrationSettings& s, int sign) {
  constexpr int kUpdatedFlag = 4;  // a bit beside the UpdateStatus values
  BlockUpdateResult result{0, 0, 0};
  const BlockInCamera b = blockInCamera(cam, coord, s.voxel_size);
  for (int z = 0; z < kBlockSide; ++z) {
    for (int y = 0; y < kBlockSide; ++y) {
      // A row's observations first (independent, branch-free: vectorised), then the updates.
      ObservationRow row;
      uint32_t row_weight = 0;
      for (int x = 0; x < kBlockSide; ++x) {
        const Observation o = observe<kWeighted>(f, cam, s, voxelInCamera(b, x, y, z));
        row.sdf[x] = o.sdf;
        row.weight[x] = o.weight;
        row.pixel[x] = o.pixel;
        row_weight |= o.weight;
      }
      if (row_weight == 0u) continue;  // a row the frame does not observe is left unread and unwritten
      Voxel* voxel_row = voxels + localIndex(0, y, z);
      if constexpr (kColor) {
        // Byte loads do not gather: this loop stays scalar.
        for (int x = 0; x < kBlockSide; ++x) row.bgr[x] = pixelBgr(f.bgr, row.pixel[x] >= 0 ? row.pixel[x] : 0);
      }
      // The row's voxels copied in and out as structure of arrays too: the
      // pool's voxels interleave three words, which GCC does not vectorise
      // (x86 has no three-way shuffles).
      int32_t sdf_sum[kBlockSide];
      uint32_t bits0[kBlockSide], bits1[kBlockSide];
      for (int x = 0; x < kBlockSide; ++x) {
        sdf_sum[x] = voxel_row[x].sdf_sum;
        bits0[x] = voxel_row[x].bits[0];
        bits1[x] = voxel_row[x].bits[1];
      }
      // Each voxel's outcome stored, then ORed: GCC vectorises neither an OR
      // reduction it has turned into a select nor one across the outer loops.
      int32_t outcome[kBlockSide];
      for (int x = 0; x < kBlockSide; ++x) {
        Voxel v{sdf_sum[x], {bits0[x], bits1[x]}};
        const bool observed = row.weight[x] != 0u;
        const int status =
            applyObservation(v, {row.sdf[x], row.weight[x], row.pixel[x]}, kColor ? row.bgr[x] : 0u, sign);
        outcome[x] = status | ((observed & (status == kUpdated)) ? kUpdatedFlag : 0);
        sdf_sum[x] = v.sdf_sum;
        bits0[x] = v.bits[0];
        bits1[x] = v.bits[1];
      }
      for (int x = 0; x < kBlockSide; ++x) voxel_row[x] = Voxel{sdf_sum[x], {bits0[x], bits1[x]}};
      int row_outcome = 0;
      for (int x = 0; x < kBlockSide; ++x) row_outcome |= outcome[x];
      result.overflow |= (row_outcome & kWeightOverflow) != 0;
      result.underflow |= (row_outcome & kWeightUnderflow) != 0;
      result.occupied |= (row_outcome & kUpdatedFlag) != 0;
    }
  }
  if (sign < 0) {
    // Occupied after de-integration: any voxel of the block, observed or not, still weighted.
    uint32_t weight = 0;
    for (int i = 0; i < kBlockVoxels; ++i) weight |= voxelWeight(voxels[i]);
    result.occupied = weight != 0u;
  }
  return result;
}
REKON_HD inline BlockUpdateResult updateBlock(Voxel* voxels, BlockCoord coord, const FrameImages& f,
                                              const CameraView& cam, const IntegrationSettings& s, int sign) {
  if (f.weights) {
    return f.bgr ? updateBlock<true, true>(voxels, coord, f, cam, s, sign)
                 : updateBlock<true, false>(voxels, coord, f, cam, s, sign);
  }
  return f.bgr ? updateBlock<false, true>(voxels, coord, f, cam, s, sign)
               : updateBlock<false, false>(voxels, coord, f, cam, s, sign);
}

// Block coordinates crossed by the truncation band of one depth pixel: the
// segment of its ray between depth - truncation and depth + truncation, walked
// through the block grid (Amanatides & Woo). Calls emit(BlockCoord) for each.
template <typename Emit>
REKON_HD inline void visitBandBlocks(const FrameImages& f, const CameraView& cam, const IntegrationSettings& s, int u,
                                     int v, Emit&& emit) {
  const int pixel = v * f.width + u;
  const float depth = f.depth[pixel];
  if (!validDepth(depth, s.max_depth)) return;
  if (pixelWeightUnits(f, pixel, s.weight_units) == 0u) return;
  const Vec3f ray{(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.f};
  const float z0 = depth - s.truncation > 1e-3f ? depth - s.truncation : 1e-3f;
  const float z1 = depth + s.truncation;
  const float block_size = kBlockSide * s.voxel_size;
  const Vec3f a = (1.f / block_size) * cameraToWorld(cam, z0 * ray);
  const Vec3f b = (1.f / block_size) * cameraToWorld(cam, z1 * ray);
  int ix = static_cast<int>(floorf(a.x)), iy = static_cast<int>(floorf(a.y)), iz = static_cast<int>(floorf(a.z));
  const int ex = static_cast<int>(floorf(b.x)), ey = static_cast<int>(floorf(b.y)), ez = static_cast<int>(floorf(b.z));
  const Vec3f d = b - a;
  const int sx = d.x > 0.f ? 1 : -1, sy = d.y > 0.f ? 1 : -1, sz = d.z > 0.f ? 1 : -1;
  const float big = 1e30f;
  const float tdx = d.x != 0.f ? fabsf(1.f / d.x) : big;
  const float tdy = d.y != 0.f ? fabsf(1.f / d.y) : big;
  const float tdz = d.z != 0.f ? fabsf(1.f / d.z) : big;
  float tx = d.x != 0.f ? ((sx > 0 ? (ix + 1 - a.x) : (a.x - ix)) * tdx) : big;
  float ty = d.y != 0.f ? ((sy > 0 ? (iy + 1 - a.y) : (a.y - iy)) * tdy) : big;
  float tz = d.z != 0.f ? ((sz > 0 ? (iz + 1 - a.z) : (a.z - iz)) * tdz) : big;
  // The segment spans at most |ex-ix|+|ey-iy|+|ez-iz| block boundaries.
  const int steps = (ex > ix ? ex - ix : ix - ex) + (ey > iy ? ey - iy : iy - ey) + (ez > iz ? ez - iz : iz - ez);
  emit(BlockCoord{ix, iy, iz});
  for (int i = 0; i < steps; ++i) {
    if (tx <= ty && tx <= tz) {
      ix += sx;
      tx += tdx;
    } else if (ty <= tz) {
      iy += sy;
      ty += tdy;
    } else {
      iz += sz;
      tz += tdz;
    }
    emit(BlockCoord{ix, iy, iz});
  }
}

// ---- Reading the volume (ray casting) ----

struct VolumeView {
  HashView table;
  const Voxel* pool;  // slot * kBlockVoxels + localIndex
  float voxel_size;
  float truncation;
};

// Voxel at integer lattice coordinates, or null when its block is absent.
REKON_HD inline const Voxel* voxelAt(const VolumeView& vol, int x, int y, int z) {
  const BlockCoord bc{floorDiv(x, kBlockSide), floorDiv(y, kBlockSide), floorDiv(z, kBlockSide)};
  const int32_t slot = findBlock(vol.table, bc);
  if (slot == kEmptySlot) return nullptr;
  return vol.pool + static_cast<int64_t>(slot) * kBlockVoxels +
         localIndex(x - bc.x * kBlockSide, y - bc.y * kBlockSide, z - bc.z * kBlockSide);
}

REKON_HD inline float voxelSdf(const Voxel& v, float truncation) {
  return static_cast<float>(v.sdf_sum) / (static_cast<float>(voxelWeight(v)) * kSdfSteps) * truncation;
}

// Trilinear signed distance (metres) at world point p; false when any of the
// eight surrounding voxels is unobserved or its block absent.
REKON_HD inline bool sampleSdf(const VolumeView& vol, Vec3f p, float& sdf) {
  const Vec3f g = (1.f / vol.voxel_size) * p;
  const int x0 = static_cast<int>(floorf(g.x)), y0 = static_cast<int>(floorf(g.y)), z0 = static_cast<int>(floorf(g.z));
  const float fx = g.x - x0, fy = g.y - y0, fz = g.z - z0;
  const BlockCoord bc{floorDiv(x0, kBlockSide), floorDiv(y0, kBlockSide), floorDiv(z0, kBlockSide)};
  const int lx = x0 - bc.x * kBlockSide, ly = y0 - bc.y * kBlockSide, lz = z0 - bc.z * kBlockSide;
  // Most samples have all eight corners in one block: one hash look-up.
  const Voxel* block = nullptr;
  if (lx < kBlockSide - 1 && ly < kBlockSide - 1 && lz < kBlockSide - 1) {
    const int32_t slot = findBlock(vol.table, bc);
    if (slot == kEmptySlot) return false;
    block = vol.pool + static_cast<int64_t>(slot) * kBlockVoxels;
  }
  float acc = 0.f;
  BlockCoord cached{bc.x - 1, bc.y - 1, bc.z - 1};  // a block no corner lies in
  const Voxel* cached_block = nullptr;
  for (int c = 0; c < 8; ++c) {
    const int ox = c & 1, oy = (c >> 1) & 1, oz = (c >> 2) & 1;
    const Voxel* v;
    if (block) {
      v = block + localIndex(lx + ox, ly + oy, lz + oz);
    } else {
      // The cell straddles blocks: look each block up once.
      const int x = x0 + ox, y = y0 + oy, z = z0 + oz;
      const BlockCoord cb{floorDiv(x, kBlockSide), floorDiv(y, kBlockSide), floorDiv(z, kBlockSide)};
      if (!(cb == cached)) {
        const int32_t slot = findBlock(vol.table, cb);
        cached = cb;
        cached_block = slot == kEmptySlot ? nullptr : vol.pool + static_cast<int64_t>(slot) * kBlockVoxels;
      }
      v = cached_block ? cached_block + localIndex(x - cb.x * kBlockSide, y - cb.y * kBlockSide, z - cb.z * kBlockSide)
                       : nullptr;
    }
    if (v == nullptr || voxelWeight(*v) == 0u) return false;
    const float w = (ox ? fx : 1.f - fx) * (oy ? fy : 1.f - fy) * (oz ? fz : 1.f - fz);
    acc += w * voxelSdf(*v, vol.truncation);
  }
  sdf = acc;
  return true;
}

// Ray parameter at which the ray leaves the block containing origin + t * dir.
REKON_HD inline float blockExit(const VolumeView& vol, Vec3f origin, Vec3f dir, float t) {
  const float side = kBlockSide * vol.voxel_size;
  const Vec3f p = origin + t * dir;
  float exit = 1e30f;
  const float o[3] = {origin.x, origin.y, origin.z}, d[3] = {dir.x, dir.y, dir.z}, q[3] = {p.x, p.y, p.z};
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0.f) continue;
    // Voxel lattice points sit at multiples of voxel_size, so block b covers
    // [b * side, (b + 1) * side) in lattice terms, shifted by half a voxel for sampling.
    const float cell = floorf(q[a] / side);
    const float boundary = (d[a] > 0.f ? cell + 1.f : cell) * side;
    const float ta = (boundary - o[a]) / d[a];
    exit = ta < exit ? ta : exit;
  }
  return exit;
}

struct RaycastPixel {
  float depth;  // along the camera z axis; 0 = no surface
  Vec3f normal; // world frame, unit; zero without a surface
  uint8_t b, g, r;
};

// Camera-depth interval per square image tile that contains every allocated
// block projecting into the tile (InfiniTAM's min/max depth image): rays
// march only there.
struct TileDepthRanges {
  const float* near;  // per tile; near > far when no block projects there
  const float* far;
  int tiles_x;
  int tile;  // pixels per tile side
};

// Marches the ray of pixel (u, v) through its tile's depth range (at most
// max_depth) and returns the first zero crossing from positive (free space)
// to negative (behind the surface).
REKON_HD inline RaycastPixel raycastPixel(const VolumeView& vol, const CameraView& cam, const TileDepthRanges& ranges,
                                          float max_depth, int u, int v) {
  RaycastPixel out{0.f, {0.f, 0.f, 0.f}, 0, 0, 0};
  const int tile = (v / ranges.tile) * ranges.tiles_x + u / ranges.tile;
  const float z_near = ranges.near[tile], z_far = ranges.far[tile] < max_depth ? ranges.far[tile] : max_depth;
  if (z_near > z_far) return out;
  const Vec3f ray_cam{(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.f};
  const float ray_len = sqrtf(dot(ray_cam, ray_cam));
  const Vec3f dir = (1.f / ray_len) * cameraDirectionToWorld(cam, ray_cam);
  const Vec3f origin = cameraCentre(cam);
  const float t_max = z_far * ray_len;
  const float min_step = vol.voxel_size * 0.5f;
  float t = z_near * ray_len > vol.voxel_size ? z_near * ray_len : vol.voxel_size;
  float prev_t = 0.f, prev_sdf = 0.f;
  bool have_prev = false;
  while (t < t_max) {
    float sdf;
    if (!sampleSdf(vol, origin + t * dir, sdf)) {
      // Unobserved here: if the whole block is absent skip to its far side,
      // else move half a truncation on, which cannot jump over the observed
      // positive half of a surface's band (a full truncation deep).
      have_prev = false;
      const Vec3f p = origin + t * dir;
      const Vec3f g = (1.f / vol.voxel_size) * p;
      const BlockCoord bc{floorDiv(static_cast<int>(floorf(g.x)), kBlockSide), floorDiv(static_cast<int>(floorf(g.y)), kBlockSide),
                          floorDiv(static_cast<int>(floorf(g.z)), kBlockSide)};
      const float exit = blockExit(vol, origin, dir, t);
      t = findBlock(vol.table, bc) == kEmptySlot && exit > t ? exit + 1e-4f : t + 0.5f * vol.truncation;
      continue;
    }
    if (have_prev && prev_sdf > 0.f && sdf <= 0.f) {
      const float ts = prev_t + (t - prev_t) * prev_sdf / (prev_sdf - sdf);
      const Vec3f p = origin + ts * dir;
      out.depth = ts / ray_len;
      const float h = vol.voxel_size;
      float sx0, sx1, sy0, sy1, sz0, sz1;
      if (sampleSdf(vol, p + Vec3f{h, 0, 0}, sx1) && sampleSdf(vol, p - Vec3f{h, 0, 0}, sx0) &&
          sampleSdf(vol, p + Vec3f{0, h, 0}, sy1) && sampleSdf(vol, p - Vec3f{0, h, 0}, sy0) &&
          sampleSdf(vol, p + Vec3f{0, 0, h}, sz1) && sampleSdf(vol, p - Vec3f{0, 0, h}, sz0)) {
        const Vec3f n{sx1 - sx0, sy1 - sy0, sz1 - sz0};
        const float len = sqrtf(dot(n, n));
        if (len > 0.f) out.normal = (1.f / len) * n;
      }
      const Vec3f g = (1.f / vol.voxel_size) * p;
      const Voxel* near_voxel = voxelAt(vol, static_cast<int>(floorf(g.x + 0.5f)), static_cast<int>(floorf(g.y + 0.5f)),
                                        static_cast<int>(floorf(g.z + 0.5f)));
      if (near_voxel != nullptr && voxelWeight(*near_voxel) != 0u) {
        out.r = voxelColor(*near_voxel, 0);
        out.g = voxelColor(*near_voxel, 1);
        out.b = voxelColor(*near_voxel, 2);
      }
      return out;
    }
    prev_t = t;
    prev_sdf = sdf;
    have_prev = true;
    const float step = sdf * 0.8f;
    t += step > min_step ? step : min_step;
  }
  return out;
}

}  // namespace rekon::volume
