// compareBackendsOnSyntheticFrames: the CUDA backend's start-up self-check
// against the CPU backend (and, in the tests, any backend against another).
#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>
#include <string>
#include <tuple>
#include <vector>

#include "rekon/mapper/volume/volume_backend.hpp"

namespace rekon::volume {
namespace {

// Small enough to cost milliseconds on the CPU backend, large enough that
// both frames together touch a few hundred blocks and tens of thousands of voxels.
constexpr int kWidth = 64, kHeight = 48;
constexpr double kFocal = 56.0;
// Fewer observed voxels than this means the scene no longer tests anything.
constexpr int64_t kMinObservedVoxels = 10000;

const IntegrationSettings kSettings{0.02f, 0.06f, 2.0f, 32.f, 1.f / 0.06f};

struct SyntheticFrame {
  std::vector<float> depth, weights;  // weights empty: every pixel weighs 1
  std::vector<uint8_t> bgr;
  CameraView cam{};
  FrameImages images() const {
    return {depth.data(), bgr.data(), weights.empty() ? nullptr : weights.data(), kWidth, kHeight};
  }
};

// A tilted plane behind a sphere, seen by a camera at `centre` turned `yaw`
// radians about the world y axis (x right, y down, z forward at yaw 0).
// Depth is exact in double, then stored as float like a converted depth image.
SyntheticFrame renderFrame(double yaw, const double centre[3], bool with_weights) {
  SyntheticFrame f;
  const double c = std::cos(yaw), s = std::sin(yaw);
  const double rcw[9] = {c, 0, s, 0, 1, 0, -s, 0, c};  // camera to world, row-major
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) f.cam.r[r * 3 + k] = static_cast<float>(rcw[k * 3 + r]);  // transpose
    f.cam.t[r] = static_cast<float>(-(rcw[0 * 3 + r] * centre[0] + rcw[1 * 3 + r] * centre[1] + rcw[2 * 3 + r] * centre[2]));
  }
  f.cam.fx = f.cam.fy = static_cast<float>(kFocal);
  f.cam.cx = (kWidth - 1) * 0.5f;
  f.cam.cy = (kHeight - 1) * 0.5f;
  f.cam.width = kWidth;
  f.cam.height = kHeight;

  const double plane_n[3] = {-0.3, 0.1, 1.0}, plane_d = 1.3;
  const double sphere_c[3] = {0.05, -0.05, 0.9}, sphere_r = 0.18;
  f.depth.resize(kWidth * kHeight);
  f.bgr.resize(kWidth * kHeight * 3);
  if (with_weights) f.weights.resize(kWidth * kHeight);
  for (int v = 0; v < kHeight; ++v) {
    for (int u = 0; u < kWidth; ++u) {
      const double dc[3] = {(u - f.cam.cx) / kFocal, (v - f.cam.cy) / kFocal, 1.0};
      double d[3], oc[3];
      for (int r = 0; r < 3; ++r) {
        d[r] = rcw[r * 3] * dc[0] + rcw[r * 3 + 1] * dc[1] + rcw[r * 3 + 2] * dc[2];
        oc[r] = centre[r] - sphere_c[r];
      }
      // The ray's parameter is the camera depth, because dc.z = 1.
      double t = std::numeric_limits<double>::infinity();
      const double nd = plane_n[0] * d[0] + plane_n[1] * d[1] + plane_n[2] * d[2];
      const double no = plane_n[0] * centre[0] + plane_n[1] * centre[1] + plane_n[2] * centre[2];
      if (std::abs(nd) > 1e-9 && (plane_d - no) / nd > 0) t = (plane_d - no) / nd;
      const double a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
      const double b = 2 * (d[0] * oc[0] + d[1] * oc[1] + d[2] * oc[2]);
      const double cc = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - sphere_r * sphere_r;
      const double disc = b * b - 4 * a * cc;
      if (disc >= 0) {
        const double ts = (-b - std::sqrt(disc)) / (2 * a);
        if (ts > 0 && ts < t) t = ts;
      }
      const int i = v * kWidth + u;
      f.depth[i] = std::isfinite(t) ? static_cast<float>(t) : 0.f;
      f.bgr[3 * i + 0] = static_cast<uint8_t>((7 * u + 3 * v) & 255);
      f.bgr[3 * i + 1] = static_cast<uint8_t>((5 * v + 40) & 255);
      f.bgr[3 * i + 2] = static_cast<uint8_t>((u * v + 11) & 255);
      if (with_weights) f.weights[i] = u == 30 ? 0.f : 0.25f + 0.25f * static_cast<float>((u + 2 * v) % 5);
    }
  }
  // Pixels every real depth image has: holes, a NaN and one beyond max_depth.
  for (int v = 5; v < 9; ++v) {
    for (int u = 5; u < 9; ++u) f.depth[v * kWidth + u] = 0.f;
  }
  f.depth[30 * kWidth + 20] = std::numeric_limits<float>::quiet_NaN();
  f.depth[10 * kWidth + 40] = 3.5f;
  return f;
}

bool coordLess(const BlockCoord& a, const BlockCoord& b) { return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z); }

void sortUnique(std::vector<BlockCoord>& coords) {
  std::sort(coords.begin(), coords.end(), coordLess);
  coords.erase(std::unique(coords.begin(), coords.end()), coords.end());
}

std::string coordText(const BlockCoord& c) {
  // Appended piece by piece: GCC 12 warns falsely (-Wrestrict) on "(" + std::to_string(...).
  std::string text(1, '(');
  text += std::to_string(c.x);
  text += ',';
  text += std::to_string(c.y);
  text += ',';
  text += std::to_string(c.z);
  text += ')';
  return text;
}

std::string voxelText(const Voxel& v) {
  return "sdf_sum " + std::to_string(v.sdf_sum) + " weight " + std::to_string(voxelWeight(v)) + " rgb " +
         std::to_string(voxelColorFixed(v, 0)) + "/" + std::to_string(voxelColorFixed(v, 1)) + "/" +
         std::to_string(voxelColorFixed(v, 2)) + " (1/64 levels)";
}

bool sameVoxel(const Voxel& a, const Voxel& b) {
  return a.sdf_sum == b.sdf_sum && a.bits[0] == b.bits[0] && a.bits[1] == b.bits[1];
}

class Lockstep {
 public:
  Lockstep(VolumeBackend& reference, VolumeBackend& candidate) : ref_(reference), cand_(candidate) {}

  // The frame's band blocks (sorted, unique) when both backends find the same ones.
  std::string band(const SyntheticFrame& f, const char* label, std::vector<BlockCoord>& out) {
    std::vector<BlockCoord> r, c;
    ref_.setFrame(f.images());
    ref_.collectBandBlocks(f.cam, kSettings, 1, r);
    cand_.setFrame(f.images());
    cand_.collectBandBlocks(f.cam, kSettings, 1, c);
    sortUnique(r);
    sortUnique(c);
    if (r != c) {
      std::vector<BlockCoord> common;
      std::set_intersection(r.begin(), r.end(), c.begin(), c.end(), std::back_inserter(common), coordLess);
      return "the band blocks of frame " + std::string(label) + " differ: " + ref_.name() + " finds " +
             std::to_string(r.size()) + ", " + cand_.name() + " " + std::to_string(c.size()) + ", " +
             std::to_string(common.size()) + " in common";
    }
    out = std::move(r);
    return "";
  }

  void allocate(const std::vector<BlockCoord>& coords) {
    coords_ = coords;
    slots_.resize(coords.size());
    for (size_t i = 0; i < coords.size(); ++i) slots_[i] = static_cast<int32_t>(i);
    for (VolumeBackend* b : {&ref_, &cand_}) {
      b->resizePool(static_cast<int32_t>(coords.size()));
      b->writeBlocks(slots_, nullptr);
    }
  }

  void grow(int32_t extra) {
    for (VolumeBackend* b : {&ref_, &cand_}) b->resizePool(static_cast<int32_t>(coords_.size()) + extra);
  }

  // (De-)integrates `f` into its band blocks on both backends and compares
  // what they report and every voxel afterwards.
  std::string step(const SyntheticFrame& f, const std::vector<BlockCoord>& band, int sign, const std::string& label) {
    std::vector<BlockRef> refs;
    for (const BlockCoord& c : band) {
      const auto it = std::lower_bound(coords_.begin(), coords_.end(), c, coordLess);
      refs.push_back({c, static_cast<int32_t>(it - coords_.begin())});
    }
    std::vector<uint8_t> empty_r, empty_c;
    ref_.setFrame(f.images());
    const FrameUpdateReport rr = ref_.updateBlocks(f.cam, kSettings, refs, sign, empty_r);
    cand_.setFrame(f.images());
    const FrameUpdateReport rc = cand_.updateBlocks(f.cam, kSettings, refs, sign, empty_c);
    last_report_ = rr;
    if (rr.weight_overflow != rc.weight_overflow || rr.weight_underflow != rc.weight_underflow) {
      return "after " + label + " the weight overflow/underflow reports differ: " + ref_.name() + " " +
             std::to_string(rr.weight_overflow) + "/" + std::to_string(rr.weight_underflow) + ", " + cand_.name() + " " +
             std::to_string(rc.weight_overflow) + "/" + std::to_string(rc.weight_underflow);
    }
    if (empty_r != empty_c) {
      int64_t differ = 0;
      for (size_t i = 0; i < empty_r.size() && i < empty_c.size(); ++i) differ += empty_r[i] != empty_c[i];
      return "after " + label + " the empty-block flags differ for " + std::to_string(differ) + " of " +
             std::to_string(refs.size()) + " blocks";
    }
    return compareVoxels(label);
  }

  std::string compareVoxels(const std::string& label) {
    std::vector<Voxel> r(coords_.size() * kBlockVoxels), c(coords_.size() * kBlockVoxels);
    ref_.readBlocks(slots_, r.data());
    cand_.readBlocks(slots_, c.data());
    int64_t differ = 0;
    size_t first = r.size();
    observed_ = 0;
    for (size_t i = 0; i < r.size(); ++i) {
      observed_ += voxelWeight(r[i]) != 0u;
      if (sameVoxel(r[i], c[i])) continue;
      if (differ++ == 0) first = i;
    }
    if (differ == 0) return "";
    const size_t block = first / kBlockVoxels, local = first % kBlockVoxels;
    return "after " + label + ": " + std::to_string(differ) + " of " + std::to_string(r.size()) +
           " voxels differ; the first, voxel " + std::to_string(local) + " of block " + coordText(coords_[block]) +
           ": " + ref_.name() + " " + voxelText(r[first]) + ", " + cand_.name() + " " + voxelText(c[first]);
  }

  int64_t observed() const { return observed_; }
  const FrameUpdateReport& lastReport() const { return last_report_; }

 private:
  VolumeBackend& ref_;
  VolumeBackend& cand_;
  std::vector<BlockCoord> coords_;
  std::vector<int32_t> slots_;
  int64_t observed_ = 0;  // voxels with weight on the reference at the last comparison
  FrameUpdateReport last_report_;  // the reference's, at the last step
};

}  // namespace

std::string compareBackendsOnSyntheticFrames(VolumeBackend& reference, VolumeBackend& candidate) {
  const double centre_a[3] = {0.0, 0.0, 0.0}, centre_b[3] = {0.04, -0.02, 0.03};
  const SyntheticFrame a = renderFrame(0.0, centre_a, false), b = renderFrame(0.12, centre_b, true);
  Lockstep run(reference, candidate);
  std::vector<BlockCoord> band_a, band_b;
  std::string failure = run.band(a, "A", band_a);
  if (failure.empty()) failure = run.band(b, "B", band_b);
  if (!failure.empty()) return failure;
  std::vector<BlockCoord> all = band_a;
  all.insert(all.end(), band_b.begin(), band_b.end());
  sortUnique(all);
  run.allocate(all);

  if (!(failure = run.step(a, band_a, +1, "integrating frame A")).empty()) return failure;
  if (!(failure = run.step(b, band_b, +1, "integrating frame B")).empty()) return failure;
  if (run.observed() < kMinObservedVoxels) {
    return "internal error: the self-check frames observed only " + std::to_string(run.observed()) +
           " voxels (at least " + std::to_string(kMinObservedVoxels) + " expected)";
  }
  run.grow(37);  // growth must keep every slot below the old size
  if (!(failure = run.compareVoxels("growing the pool")).empty()) return failure;
  if (!(failure = run.step(b, band_b, -1, "de-integrating frame B")).empty()) return failure;
  if (!(failure = run.step(a, band_a, -1, "de-integrating frame A")).empty()) return failure;
  if (run.observed() != 0) {
    return "after de-integrating both frames " + std::to_string(run.observed()) + " voxels of the " +
           reference.name() + " backend still carry weight (de-integration must be exact)";
  }
  // Nothing is left to remove: both must report the underflow and change nothing.
  if (!(failure = run.step(b, band_b, -1, "de-integrating frame B a second time")).empty()) return failure;
  if (!run.lastReport().weight_underflow) {
    return "de-integrating frame B a second time did not report a weight underflow on the " + reference.name() + " backend";
  }
  return "";
}

}  // namespace rekon::volume
