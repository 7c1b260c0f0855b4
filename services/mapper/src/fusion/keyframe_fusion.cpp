#include "rekon/mapper/fusion/keyframe_fusion.hpp"

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "rekon/common/error.hpp"
#include "rekon/common/simd.hpp"

namespace rekon::fusion {

KeyframeStrategy parseStrategy(const std::string& text) {
  if (text == "const") return KeyframeStrategy::kConst;
  if (text == "dvo") return KeyframeStrategy::kDvo;
  if (text == "dist") return KeyframeStrategy::kDist;
  if (text == "overlap") return KeyframeStrategy::kOverlap;
  throw Error("mapper.strategy '" + text + "' is unknown; use const, dvo, dist or overlap");
}

std::string toString(KeyframeStrategy s) {
  switch (s) {
    case KeyframeStrategy::kConst: return "const";
    case KeyframeStrategy::kDvo: return "dvo";
    case KeyframeStrategy::kDist: return "dist";
    case KeyframeStrategy::kOverlap: return "overlap";
  }
  return "?";
}

void FusionParams::validate() const {
  auto require = [](bool ok, const std::string& what) {
    if (!ok) throw Error("mapper." + what);
  };
  require(kappa >= 1, "kappa must be at least 1 (frames per KF keyframe)");
  require(max_frames_per_keyframe >= 1, "max_frames_per_keyframe must be at least 1");
  require(strategy != KeyframeStrategy::kConst || kappa <= max_frames_per_keyframe,
          "kappa (" + std::to_string(kappa) + ") exceeds mapper.max_frames_per_keyframe (" +
              std::to_string(max_frames_per_keyframe) + "); raise the cap or lower kappa");
  require(dist_translation > 0 && dist_rotation_deg > 0, "dist_translation and dist_rotation_deg must be positive");
  require(min_overlap > 0 && min_overlap < 1, "min_overlap must lie in (0, 1)");
  require(min_depth > 0 && max_depth > min_depth, "min_depth must be positive and below max_depth");
  require(max_depth_step > 0, "max_depth_step must be positive");
  require(depth_agreement > 0, "depth_agreement must be positive");
  require(unsharp_sigma > 0 && unsharp_amount >= 0, "unsharp_sigma must be positive and unsharp_amount not negative");
}

FusionParams fusionParamsFromConfig(const Config& c) {
  FusionParams p;
  p.strategy = parseStrategy(c.getString("mapper.strategy"));
  p.kappa = c.getInt("mapper.kappa");
  p.max_frames_per_keyframe = c.getInt("mapper.max_frames_per_keyframe");
  p.dist_translation = c.getDouble("mapper.dist_translation");
  p.dist_rotation_deg = c.getDouble("mapper.dist_rotation_deg");
  p.min_overlap = c.getDouble("mapper.min_overlap");
  p.min_depth = c.getDouble("mapper.min_depth");
  p.max_depth = c.getDouble("volume.max_depth");
  p.max_depth_step = c.getDouble("mapper.max_depth_step");
  p.depth_agreement = c.getDouble("mapper.depth_agreement");
  p.unsharp_sigma = c.getDouble("mapper.unsharp_sigma");
  p.unsharp_amount = c.getDouble("mapper.unsharp_amount");
  p.validate();
  return p;
}

namespace {

Eigen::Vector3d backProject(const Intrinsics& k, double u, double v, double z) {
  return {(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z};
}

cv::Mat toMetres(const cv::Mat& raw, double depth_scale) {
  if (raw.type() != CV_16UC1) throw Error("keyframe fusion: depth must be 16-bit (CV_16UC1)");
  cv::Mat m;
  raw.convertTo(m, CV_32F, 1.0 / depth_scale);
  return m;
}

// The pinhole camera in float for the per-pixel loops (their double and
// std::lround versions were a third of the mapper's time), multiplying by
// reciprocals (add() 12 -> 8 ms per 640x480 frame without the divisions).
struct PinholeF {
  float fx, fy, cx, cy, inv_fx, inv_fy;
  int width, height;
  explicit PinholeF(const Intrinsics& k)
      : fx(static_cast<float>(k.fx)), fy(static_cast<float>(k.fy)), cx(static_cast<float>(k.cx)),
        cy(static_cast<float>(k.cy)), inv_fx(1.0f / fx), inv_fy(1.0f / fy), width(k.width), height(k.height) {}
};

// What warpRow and landRow take from the camera and the transform for one
// row, in locals the compiler keeps in registers.
struct RowTransform {
  float r00, r01, r02, r10, r11, r12, r20, r21, r22, t0, t1, t2;
  float fx, fy, cx, cy, inv_fx, ry, w_max, h_max;
  int width;
  RowTransform(const PinholeF& cam, const Eigen::Matrix3f& r, const Eigen::Vector3f& t, int y)
      : r00(r(0, 0)), r01(r(0, 1)), r02(r(0, 2)), r10(r(1, 0)), r11(r(1, 1)), r12(r(1, 2)), r20(r(2, 0)),
        r21(r(2, 1)), r22(r(2, 2)), t0(t.x()), t1(t.y()), t2(t.z()), fx(cam.fx), fy(cam.fy), cx(cam.cx), cy(cam.cy),
        inv_fx(cam.inv_fx), ry((static_cast<float>(y) - cam.cy) * cam.inv_fy),
        w_max(static_cast<float>(cam.width) - 0.5f), h_max(static_cast<float>(cam.height) - 0.5f), width(cam.width) {}
};

// One keyframe row seen by one input: where each keyframe pixel lands (uf,
// vf) and whether the input saw that very surface there (inside its image,
// its depth within `agree` of the warped depth: not an occluder in front) and
// with what weight. Written so that the compiler vectorises it (checked with
// -fopt-info-vec): no branches, selects as a > b ? a : b (fmax would keep NaN
// rules), the transform in locals, outputs that alias nothing, int32 flags.
// Outside pixels read a clamped pixel and are not seen. The color samples are
// taken afterwards, for the pixels seen.
struct RowWarp {
  std::vector<float> uf, vf, w;
  std::vector<int32_t> seen;
  explicit RowWarp(int width) : uf(width), vf(width), w(width), seen(width) {}
};


// (The outputs are __restrict parameters: GCC honours restrict on parameters.)
REKON_SIMD_CLONES void warpRow(const float* __restrict zrow, int y, const PinholeF& cam, const Eigen::Matrix3f& rotation,
                               const Eigen::Vector3f& translation, const float* __restrict zw, float agree,
                               float* __restrict uf_out, float* __restrict vf_out, float* __restrict w_out,
                               int32_t* __restrict seen_out) {
  const RowTransform m(cam, rotation, translation, y);
  for (int x = 0; x < m.width; ++x) {
    const float z = zrow[x];
    const float rx = (static_cast<float>(x) - m.cx) * m.inv_fx;
    const float px = rx * z, py = m.ry * z;
    const float qx = m.r00 * px + m.r01 * py + m.r02 * z + m.t0;
    const float qy = m.r10 * px + m.r11 * py + m.r12 * z + m.t1;
    const float qz = m.r20 * px + m.r21 * py + m.r22 * z + m.t2;
    const float inv_z = 1.0f / selectMax(qz, 1e-6f);
    const float uf = m.fx * qx * inv_z + m.cx, vf = m.fy * qy * inv_z + m.cy;
    const bool inside = (z > 0) & (qz > 0) & (uf > -0.5f) & (vf > -0.5f) & (uf < m.w_max) & (vf < m.h_max);
    const int u = static_cast<int>(selectMin(selectMax(uf, 0.f), m.w_max - 0.5f) + 0.5f);
    const int v = static_cast<int>(selectMin(selectMax(vf, 0.f), m.h_max - 0.5f) + 0.5f);
    const int k = 2 * (v * m.width + u);
    const float depth = zw[k], weight = zw[k + 1];
    uf_out[x] = uf;
    vf_out[x] = vf;
    w_out[x] = weight;
    seen_out[x] = (inside & (weight > 0) & (std::abs(depth - qz) <= agree * qz)) ? 1 : 0;
  }
}

// Where each pixel of one input row lands in the keyframe (add(), eq. 1):
// the index of the keyframe pixel nearest to it, or -1 where it does not
// land (no depth weight, behind the keyframe's camera, outside its image),
// and its depth there. Branch-free like warpRow, so that it vectorises
// (add() 9.5 -> 8.1 ms per frame, rekon_fusion_benchmark); without FMA
// contraction (which GCC does in C++ by default), so that the AVX2 clone
// gives the bits of the baseline build and of the pixel-by-pixel loop with
// Eigen it replaced (rekon_fusion_benchmark --dump / --compare: identical
// KF keyframes). The color pass keeps its FMAs: without them finish() took
// 18 ms more per KF keyframe.
REKON_SIMD_CLONES __attribute__((optimize("fp-contract=off"))) void landRow(
    const float* __restrict zrow, const float* __restrict wrow, int y, const PinholeF& cam,
    const Eigen::Matrix3f& rotation, const Eigen::Vector3f& translation, int32_t* __restrict index_out,
    float* __restrict z_out) {
  const RowTransform m(cam, rotation, translation, y);
  for (int x = 0; x < m.width; ++x) {
    const float z = zrow[x];
    const float px = (static_cast<float>(x) - m.cx) * m.inv_fx * z, py = m.ry * z;
    // Summed as Eigen sums a 3-vector product, a + (b + c): the bits add() had with Eigen.
    const float qx = m.r00 * px + (m.r01 * py + m.r02 * z) + m.t0;
    const float qy = m.r10 * px + (m.r11 * py + m.r12 * z) + m.t1;
    const float qz = m.r20 * px + (m.r21 * py + m.r22 * z) + m.t2;
    const float inv_z = 1.0f / selectMax(qz, 1e-6f);
    const float uf = m.fx * qx * inv_z + m.cx, vf = m.fy * qy * inv_z + m.cy;
    const bool lands = (wrow[x] > 0) & (qz > 0) & (uf > -0.5f) & (vf > -0.5f) & (uf < m.w_max) & (vf < m.h_max);
    const int u = static_cast<int>(selectMin(selectMax(uf, 0.f), m.w_max - 0.5f) + 0.5f);
    const int v = static_cast<int>(selectMin(selectMax(vf, 0.f), m.h_max - 0.5f) + 0.5f);
    index_out[x] = lands ? v * m.width + u : -1;
    z_out[x] = qz;
  }
}

// The color observations one input makes of one keyframe row, stored per
// input (structure of arrays: contiguous stores that vectorise): where warpRow
// saw the surface and the bilinear sample lies inside the image, the sample's
// luma, weight and color (B, G, R in the low three bytes); elsewhere weight 0.
// The pixel reads are 32-bit loads of a BGR pixel (in the AVX2 clone GCC 12
// vectorises them as element-wise inserts, vpinsrd, not gathers); the last
// pixel of the image is read ending on its last byte, so no load leaves the
// image. No contraction into FMA: the same bits as sampling
// pixel by pixel in the baseline build.
REKON_SIMD_CLONES void observeRow(
    const float* __restrict uf, const float* __restrict vf, const float* __restrict w, const int32_t* __restrict seen,
    const uint8_t* __restrict image, int step, int cols, int rows, int width, float* __restrict luma_out,
    float* __restrict w_out, uint32_t* __restrict bgr_out) {
  const float u_max = static_cast<float>(cols - 1), v_max = static_cast<float>(rows - 1);
  for (int x = 0; x < width; ++x) {
    const float u = uf[x], v = vf[x];
    const bool inside = (seen[x] != 0) & (u >= 0) & (v >= 0) & (u <= u_max) & (v <= v_max);
    const float uc = selectMin(selectMax(u, 0.f), u_max), vc = selectMin(selectMax(v, 0.f), v_max);
    const int x0 = std::min(static_cast<int>(uc), cols - 2), y0 = std::min(static_cast<int>(vc), rows - 2);
    const float a = uc - static_cast<float>(x0), b = vc - static_cast<float>(y0);
    const float w00 = (1 - a) * (1 - b), w01 = a * (1 - b), w10 = (1 - a) * b, w11 = a * b;
    const int o00 = y0 * step + 3 * x0, o10 = o00 + step;
    uint32_t p00, p01, p10, p11;
    std::memcpy(&p00, image + o00, 4);
    std::memcpy(&p01, image + o00 + 3, 4);
    std::memcpy(&p10, image + o10, 4);
    std::memcpy(&p11, image + o10 + 2, 4);
    p11 >>= 8;
    float c[3];
    for (int k = 0; k < 3; ++k) {
      const int sh = 8 * k;
      c[k] = w00 * static_cast<float>((p00 >> sh) & 0xffu) + w01 * static_cast<float>((p01 >> sh) & 0xffu) +
             w10 * static_cast<float>((p10 >> sh) & 0xffu) + w11 * static_cast<float>((p11 >> sh) & 0xffu);
    }
    uint32_t packed = 0;
    for (int k = 0; k < 3; ++k) packed |= static_cast<uint32_t>(static_cast<int>(selectMin(255.0f, c[k] + 0.5f))) << (8 * k);
    luma_out[x] = 0.114f * c[0] + 0.587f * c[1] + 0.299f * c[2];
    w_out[x] = inside ? w[x] : 0.f;
    bgr_out[x] = packed;
  }
}

// Weighted median by luminance of a row's pixels, each pixel's observations
// `n` inputs' entries `stride` apart (weight 0: none): per pixel the
// observation of least luma (ties: the earlier input) whose cumulative weight
// in luma order, its own included, reaches half the total; it keeps its whole
// color (no mixed hues). By selection rather than sorting, every pixel of the
// row at once: each input's observation's cumulative weight is the weight of
// the observations before it in luma order, summed input by input, plus its
// own: n^2 masked adds over the row that vectorise, where an insertion sort
// per pixel mispredicted its branches. `best` gets the chosen input per pixel
// (-1: no observation); the other outputs are scratch of `width` floats.
REKON_SIMD_CLONES void weightedMedianRow(const float* __restrict luma, const float* __restrict w, size_t stride, int n,
                                         int width, float* __restrict total, float* __restrict before,
                                         float* __restrict best_luma, int32_t* __restrict best) {
  for (int x = 0; x < width; ++x) {
    total[x] = 0;
    best_luma[x] = std::numeric_limits<float>::max();
    best[x] = -1;
  }
  for (int i = 0; i < n; ++i) {
    const float* wi = w + static_cast<size_t>(i) * stride;
    for (int x = 0; x < width; ++x) total[x] += wi[x];
  }
  for (int j = 0; j < n; ++j) {
    const float* lj = luma + static_cast<size_t>(j) * stride;
    const float* wj = w + static_cast<size_t>(j) * stride;
    for (int x = 0; x < width; ++x) before[x] = 0;
    for (int i = 0; i < n; ++i) {
      const float* li = luma + static_cast<size_t>(i) * stride;
      const float* wi = w + static_cast<size_t>(i) * stride;
      if (i < j) {  // an earlier input comes first at equal luma
        for (int x = 0; x < width; ++x) before[x] += li[x] <= lj[x] ? wi[x] : 0.f;
      } else if (i > j) {
        for (int x = 0; x < width; ++x) before[x] += li[x] < lj[x] ? wi[x] : 0.f;
      }
    }
    for (int x = 0; x < width; ++x) {
      // Of the observations reaching half, the least luma; at equal luma the earlier input (strict <).
      const bool chosen = (wj[x] > 0) & (before[x] + wj[x] >= 0.5f * total[x]) & (lj[x] < best_luma[x]);
      best_luma[x] = chosen ? lj[x] : best_luma[x];
      best[x] = chosen ? j : best[x];
    }
  }
}

}  // namespace

// Written without branches (each test a mask, every pixel computes), so that
// the compiler vectorises the row; the same weights as testing pixel by pixel.
cv::Mat depthWeights(const cv::Mat& depth, const Intrinsics& k, const FusionParams& p) {
  cv::Mat w(depth.size(), CV_32F, cv::Scalar(0));
  const float zmin = static_cast<float>(p.min_depth), zmax = static_cast<float>(p.max_depth);
  const float step = static_cast<float>(p.max_depth_step);
  const PinholeF cam(k);
  for (int y = 1; y + 1 < depth.rows; ++y) {
    const float* up = depth.ptr<float>(y - 1);
    const float* row = depth.ptr<float>(y);
    const float* down = depth.ptr<float>(y + 1);
    float* out = w.ptr<float>(y);
    const float ry = (static_cast<float>(y) - cam.cy) * cam.inv_fy;
    const float ry_up = ry - cam.inv_fy, ry_down = ry + cam.inv_fy;
    for (int x = 1; x + 1 < depth.cols; ++x) {
      const float z = row[x], zl = row[x - 1], zr = row[x + 1], zu = up[x], zd = down[x];
      const float limit = step * z;
      // & rather than &&: no short-circuit branches in the loop.
      const bool ok = (z >= zmin) & (z <= zmax) & (zl > 0) & (zr > 0) & (zu > 0) & (zd > 0) &
                      (std::abs(zl - z) <= limit) & (std::abs(zr - z) <= limit) & (std::abs(zu - z) <= limit) &
                      (std::abs(zd - z) <= limit);
      // Depth normal from central differences of the back-projected points.
      const float rx = (static_cast<float>(x) - cam.cx) * cam.inv_fx;
      const float dx0 = (rx + cam.inv_fx) * zr - (rx - cam.inv_fx) * zl, dx1 = ry * (zr - zl), dx2 = zr - zl;
      const float dy0 = rx * (zd - zu), dy1 = ry_down * zd - ry_up * zu, dy2 = zd - zu;
      const float n0 = dx1 * dy2 - dx2 * dy1, n1 = dx2 * dy0 - dx0 * dy2, n2 = dx0 * dy1 - dx1 * dy0;
      const float norm2 = n0 * n0 + n1 * n1 + n2 * n2;
      const bool valid = ok & (norm2 > 0);
      // cos(theta) / z^2, with sqrt and divisions of valid pixels only.
      const float safe_norm2 = valid ? norm2 : 1.f, safe_z = valid ? z : 1.f;
      const float weight = std::abs(n2) / (std::sqrt(safe_norm2) * safe_z * safe_z);
      out[x] = valid ? weight : 0.f;
    }
  }
  return w;
}

double blurriness(const cv::Mat& color_bgr) {
  cv::Mat gray;
  cv::cvtColor(color_bgr, gray, cv::COLOR_BGR2GRAY);
  gray.convertTo(gray, CV_32F);
  // The blur metric re-blurs with a 9-tap box filter along each direction and
  // measures how much neighbour variation the re-blur removes: a sharp image
  // loses much, a blurred one little.
  cv::Mat b_ver, b_hor;
  cv::blur(gray, b_ver, cv::Size(1, 9));
  cv::blur(gray, b_hor, cv::Size(9, 1));
  // A row's sums in float (vectorised; at most 640 x 255 each), the image's in double.
  double s_f_ver = 0, s_v_ver = 0, s_f_hor = 0, s_v_hor = 0;
  for (int y = 1; y < gray.rows; ++y) {
    const float* f0 = gray.ptr<float>(y - 1);
    const float* f1 = gray.ptr<float>(y);
    const float* bv0 = b_ver.ptr<float>(y - 1);
    const float* bv1 = b_ver.ptr<float>(y);
    const float* bh = b_hor.ptr<float>(y);
    float r_f_ver = 0, r_v_ver = 0, r_f_hor = 0, r_v_hor = 0;
    for (int x = 1; x < gray.cols; ++x) {
      const float d_f_ver = std::abs(f1[x] - f0[x]), d_b_ver = std::abs(bv1[x] - bv0[x]);
      const float d_f_hor = std::abs(f1[x] - f1[x - 1]), d_b_hor = std::abs(bh[x] - bh[x - 1]);
      r_f_ver += d_f_ver;
      r_v_ver += std::max(0.0f, d_f_ver - d_b_ver);
      r_f_hor += d_f_hor;
      r_v_hor += std::max(0.0f, d_f_hor - d_b_hor);
    }
    s_f_ver += r_f_ver;
    s_v_ver += r_v_ver;
    s_f_hor += r_f_hor;
    s_v_hor += r_v_hor;
  }
  if (s_f_ver <= 0 || s_f_hor <= 0) return 1.0;  // a flat image carries no sharpness
  return std::max((s_f_ver - s_v_ver) / s_f_ver, (s_f_hor - s_v_hor) / s_f_hor);
}

cv::Mat unsharpMask(const cv::Mat& color_bgr, double sigma, double amount) {
  cv::Mat blurred, sharp;
  cv::GaussianBlur(color_bgr, blurred, cv::Size(0, 0), sigma);
  cv::addWeighted(color_bgr, 1.0 + amount, blurred, -amount, 0.0, sharp);
  return sharp;
}

double overlapRatio(const cv::Mat& kd, const Intrinsics& k, const Pose& frame_from_keyframe) {
  int valid = 0, seen = 0;
  for (int y = 0; y < kd.rows; y += 4) {
    const float* row = kd.ptr<float>(y);
    for (int x = 0; x < kd.cols; x += 4) {
      if (!(row[x] > 0)) continue;
      ++valid;
      const Eigen::Vector3d p = frame_from_keyframe * backProject(k, x, y, row[x]);
      if (p.z() <= 0) continue;
      const double u = k.fx * p.x() / p.z() + k.cx, v = k.fy * p.y() / p.z() + k.cy;
      seen += u >= 0 && v >= 0 && u <= k.width - 1 && v <= k.height - 1;
    }
  }
  return valid == 0 ? 0.0 : static_cast<double>(seen) / valid;
}

KeyframeFuser::KeyframeFuser(const FusionParams& params, const Intrinsics& k) : params_(params), k_(k) {
  params_.validate();
}

bool KeyframeFuser::startsNewKeyframe(int64_t dvo_keyframe_id, const Pose& camera_to_world) const {
  if (!open_ || frames_ >= params_.max_frames_per_keyframe) return true;
  switch (params_.strategy) {
    case KeyframeStrategy::kConst: return frames_ >= params_.kappa;
    case KeyframeStrategy::kDvo: return dvo_keyframe_id != dvo_keyframe_id_;
    case KeyframeStrategy::kDist:
      return translationDistance(kf_world_, camera_to_world) > params_.dist_translation ||
             rotationAngle(kf_world_, camera_to_world) * 180.0 / M_PI > params_.dist_rotation_deg;
    case KeyframeStrategy::kOverlap:
      return overlapRatio(kf_.depth, k_, camera_to_world.inverse() * kf_world_) < params_.min_overlap;
  }
  return true;
}

size_t KeyframeFuser::heldInputBytes() const {
  size_t bytes = 0;
  for (const ColorInput& in : inputs_) bytes += in.sharp.total() * in.sharp.elemSize() + in.depth_weight.total() * in.depth_weight.elemSize();
  return bytes;
}

void KeyframeFuser::begin(int64_t kf_id, int64_t anchor_keyframe_id, const Pose& pose_in_anchor,
                          const Pose& camera_to_world) {
  kf_ = FusedKeyframe{};
  kf_.id = kf_id;
  kf_.anchor_keyframe_id = anchor_keyframe_id;
  kf_.pose_in_anchor = pose_in_anchor;
  kf_.depth = cv::Mat(k_.height, k_.width, CV_32F, cv::Scalar(0));
  kf_.weight = cv::Mat(k_.height, k_.width, CV_32F, cv::Scalar(0));
  kf_world_ = camera_to_world;
  dvo_keyframe_id_ = anchor_keyframe_id;
  frames_ = 0;
  open_ = true;
  inputs_.clear();
}

void KeyframeFuser::add(const RgbdFrame& frame, const Pose& camera_to_world) {
  if (!open_) throw Error("keyframe fusion: add() before begin()");
  if (frame.depth.cols != k_.width || frame.depth.rows != k_.height || frame.color.size() != frame.depth.size() ||
      frame.color.type() != CV_8UC3)
    throw Error("keyframe fusion: frame " + std::to_string(frame.id) + " does not match the " +
                std::to_string(k_.width) + "x" + std::to_string(k_.height) + " camera (16-bit depth, BGR color)");
  const cv::Mat depth = toMetres(frame.depth, k_.depth_scale);
  const cv::Mat w_z = depthWeights(depth, k_, params_);
  const Pose kf_from_frame = kf_world_.inverse() * camera_to_world;
  const Eigen::Matrix3f r = kf_from_frame.linear().cast<float>();
  const Eigen::Vector3f t = kf_from_frame.translation().cast<float>();
  const PinholeF cam(k_);
  const float agree = static_cast<float>(params_.depth_agreement);
  std::vector<int32_t> index(static_cast<size_t>(depth.cols));
  std::vector<float> landed_z(index.size());
  auto* kd = kf_.depth.ptr<float>();
  auto* kw = kf_.weight.ptr<float>();
  for (int y = 0; y < depth.rows; ++y) {
    const float* wrow = w_z.ptr<float>(y);
    landRow(depth.ptr<float>(y), wrow, y, cam, r, t, index.data(), landed_z.data());
    // Serial: two frame pixels may land on the same keyframe pixel.
    for (int x = 0; x < depth.cols; ++x) {
      const int32_t at = index[static_cast<size_t>(x)];
      if (at < 0) continue;
      const float w = wrow[x], qz = landed_z[static_cast<size_t>(x)];
      float& zk = kd[at];
      float& wk = kw[at];
      if (wk > 0 && std::abs(qz - zk) > agree * zk) {
        if (qz > zk) continue;  // behind the keyframe's surface: occluded
        wk = 0;                 // in front: a nearer surface replaces the old one
      }
      zk = (wk * zk + w * qz) / (wk + w);  // eq. (1)
      wk += w;
    }
  }
  ColorInput in;
  in.sharp = unsharpMask(frame.color, params_.unsharp_sigma, params_.unsharp_amount);
  const float w_b = static_cast<float>(std::max(1e-3, 1.0 - blurriness(frame.color)));
  cv::merge(std::vector<cv::Mat>{depth, w_z * w_b}, in.depth_weight);
  in.keyframe_to_camera = camera_to_world.inverse() * kf_world_;
  inputs_.push_back(std::move(in));
  if (frames_ == 0) {
    kf_.first_frame_id = frame.id;
    kf_.timestamp = frame.timestamp;
  }
  kf_.last_frame_id = frame.id;
  ++frames_;
}

FusedKeyframe KeyframeFuser::finish() {
  if (frames_ == 0) throw Error("keyframe fusion: finish() without frames (begin() and add() first)");
  kf_.frames = frames_;
  kf_.color = cv::Mat(k_.height, k_.width, CV_8UC3, cv::Scalar(0, 0, 0));
  std::vector<Eigen::Matrix3f> rotations;
  std::vector<Eigen::Vector3f> translations;
  for (const ColorInput& in : inputs_) {
    rotations.push_back(in.keyframe_to_camera.linear().cast<float>());
    translations.push_back(in.keyframe_to_camera.translation().cast<float>());
  }
  const PinholeF cam(k_);
  const float agree = static_cast<float>(params_.depth_agreement);
  // Bands of rows are independent. Within a band, input after input: reading
  // one input at a time keeps its images streaming through the cache (pixel
  // after pixel over all inputs missed it on nearly every input). A band's
  // observations lie input by input (each input's for the band's pixels
  // contiguous), so each row's are written as contiguous arrays.
  constexpr int kBandRows = 8;
  const int width = k_.width, n = static_cast<int>(inputs_.size());
  // One input's stretch is a band's pixels and one cache line more: a multiple
  // of 4 KiB (8 x 640 floats) would put a pixel's entries of every input in
  // one L1 set, which holds only 8 of them.
  const size_t band_pixels = static_cast<size_t>(kBandRows) * static_cast<size_t>(width) + 16;
  cv::parallel_for_(cv::Range(0, (k_.height + kBandRows - 1) / kBandRows), [&](const cv::Range& bands) {
    std::vector<float> luma(band_pixels * static_cast<size_t>(n)), weight(luma.size());
    std::vector<uint32_t> bgr(luma.size());
    std::vector<float> total(static_cast<size_t>(width)), before(total.size()), best_luma(total.size());
    std::vector<int32_t> best(total.size());
    RowWarp warp(width);
    for (int band = bands.start; band < bands.end; ++band) {
      const int y0 = band * kBandRows, y1 = std::min(y0 + kBandRows, k_.height);
      for (int i = 0; i < n; ++i) {
        const ColorInput& in = inputs_[static_cast<size_t>(i)];
        for (int y = y0; y < y1; ++y) {
          warpRow(kf_.depth.ptr<float>(y), y, cam, rotations[static_cast<size_t>(i)],
                  translations[static_cast<size_t>(i)], in.depth_weight.ptr<float>(), agree, warp.uf.data(),
                  warp.vf.data(), warp.w.data(), warp.seen.data());
          const size_t at = static_cast<size_t>(i) * band_pixels + static_cast<size_t>(y - y0) * width;
          observeRow(warp.uf.data(), warp.vf.data(), warp.w.data(), warp.seen.data(), in.sharp.data, static_cast<int>(in.sharp.step),
                     in.sharp.cols, in.sharp.rows, width, luma.data() + at, weight.data() + at, bgr.data() + at);
        }
      }
      for (int y = y0; y < y1; ++y) {
        const size_t row = static_cast<size_t>(y - y0) * width;
        weightedMedianRow(luma.data() + row, weight.data() + row, band_pixels, n, width, total.data(), before.data(),
                          best_luma.data(), best.data());
        auto* crow = kf_.color.ptr<cv::Vec3b>(y);
        for (int x = 0; x < width; ++x) {
          if (best[static_cast<size_t>(x)] < 0) continue;
          const uint32_t c = bgr[static_cast<size_t>(best[static_cast<size_t>(x)]) * band_pixels + row + x];
          crow[x] = cv::Vec3b(static_cast<uint8_t>(c), static_cast<uint8_t>(c >> 8), static_cast<uint8_t>(c >> 16));
        }
      }
    }
  });
  inputs_.clear();
  frames_ = 0;
  open_ = false;
  return std::move(kf_);
}

}  // namespace rekon::fusion
