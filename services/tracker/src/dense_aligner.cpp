#include "rekon/tracker/dense_aligner.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/common/simd.hpp"

namespace rekon::tracker {
namespace {

// Floors of the residual scales: noise-free synthetic frames drive the
// residuals to zero, and a singular scale matrix would give infinite weights.
constexpr double kMinIntensitySigma = 1e-4;  // intensity 0..1
constexpr double kMinDepthSigma = 1e-5;      // metres
constexpr double kMaxCorrelation = 0.99;
constexpr int kScaleIterations = 5;
constexpr double kScaleTolerance = 1e-2;  // relative change that ends the EM of the scale
// Pixels per block of the normal-equation sums: float within a block, double
// across blocks. The block (7 columns of 2 rows per pixel, 14 KiB) stays in
// the L1 cache beside the 15 input streams that fill it (512 pixels, 28 KiB,
// and 128 took a larger share of tracker_bench's profile).
constexpr int kBlockPixels = 256;

void clampScale(double& s11, double& s12, double& s22, bool use_depth) {
  s11 = std::max(s11, kMinIntensitySigma * kMinIntensitySigma);
  if (!use_depth) {
    s22 = 1.0;
    s12 = 0.0;
    return;
  }
  s22 = std::max(s22, kMinDepthSigma * kMinDepthSigma);
  const double limit = kMaxCorrelation * std::sqrt(s11 * s22);
  s12 = std::clamp(s12, -limit, limit);
}

}  // namespace

Matrix6d AlignResult::covariance() const {
  Eigen::LLT<Matrix6d> llt(information);
  if (!valid || llt.info() != Eigen::Success) return Matrix6d::Zero();
  return llt.solve(Matrix6d::Identity());
}

double entropyOfInformation(const Matrix6d& information) {
  const Eigen::LLT<Matrix6d> llt(information);
  if (llt.info() != Eigen::Success || !information.allFinite()) return std::numeric_limits<double>::infinity();
  double log_det = 0.0;
  for (int i = 0; i < 6; ++i) log_det += 2.0 * std::log(llt.matrixL()(i, i));
  return 3.0 * (1.0 + std::log(2.0 * std::numbers::pi)) - 0.5 * log_det;
}

DenseAligner::DenseAligner(const AlignerParams& params) : params_(params) { params_.validate(); }

namespace {


struct WarpConstants {
  float r00, r01, r02, t0, r10, r11, r12, t1, r20, r21, r22, t2;
  float fx, fy, cx, cy, umax, vmax, zmin, max_step;
  int width;
  float use_depth;  // 1 or 0: a float, so that its test vectorises as a mask like the others
};

// Every reference point in one pass, written so that the compiler vectorises
// it (-fopt-info-vec): no branches (each test a mask), selects as a > b ? a :
// b, outputs that alias nothing (restrict parameters). A point that does not
// count reads a clamped pixel and gets valid = 0 and residuals 0, so that the
// passes after it run over every point in order (contiguous loads, no
// gathers) and it adds nothing to their sums. Same arithmetic as testing
// point by point. Returns the number of points that count.
REKON_SIMD_CLONES int warpPoints(const float* __restrict points, int count, const float* __restrict intensity,
                                 const float* __restrict depth, const WarpConstants c, float* __restrict res_i,
                                 float* __restrict res_z, float* __restrict valid) {
  int n = 0;
#pragma omp simd reduction(+ : n)
  for (int i = 0; i < count; ++i) {
    const bool use_depth = c.use_depth > 0.f;
    const float* p = points + KeyframeReference::kPointStride * i;
    const float z = c.r20 * p[0] + c.r21 * p[1] + c.r22 * p[2] + c.t2;
    const float iz = 1.f / selectMax(z, 1e-6f);
    const float u = c.fx * (c.r00 * p[0] + c.r01 * p[1] + c.r02 * p[2] + c.t0) * iz + c.cx;
    const float v = c.fy * (c.r10 * p[0] + c.r11 * p[1] + c.r12 * p[2] + c.t1) * iz + c.cy;
    const bool inside = (z > c.zmin) & (u >= 0.f) & (v >= 0.f) & (u < c.umax) & (v < c.vmax);
    const float uc = selectMin(selectMax(u, 0.f), c.umax), vc = selectMin(selectMax(v, 0.f), c.vmax);
    const int x0 = static_cast<int>(uc), y0 = static_cast<int>(vc);
    const float ax = uc - static_cast<float>(x0), ay = vc - static_cast<float>(y0);
    const int o = y0 * c.width + x0;
    const float d00 = depth[o], d01 = depth[o + 1], d10 = depth[o + c.width], d11 = depth[o + c.width + 1];
    const float sum = d00 + d01 + d10 + d11;
    const float lo = selectMin(selectMin(d00, d01), selectMin(d10, d11));
    const float hi = selectMax(selectMax(d00, d01), selectMax(d10, d11));
    // Interpolating across a hole or an occlusion edge would invent a surface.
    const bool depth_ok = (sum == sum) & !(hi - lo > c.max_step * lo);
    const float dtop = d00 + ax * (d01 - d00), dbottom = d10 + ax * (d11 - d10);
    const float i00 = intensity[o], i01 = intensity[o + 1], i10 = intensity[o + c.width],
                i11 = intensity[o + c.width + 1];
    const float itop = i00 + ax * (i01 - i00), ibottom = i10 + ax * (i11 - i10);
    const bool keep = inside & (depth_ok | !use_depth);
    // Both residuals computed, then selected: GCC 12 does not vectorise the
    // loop with the selects around the expressions ("control flow in loop").
    const float ri = itop + ay * (ibottom - itop) - p[3], rz = dtop + ay * (dbottom - dtop) - z;
    res_i[i] = keep ? ri : 0.f;
    res_z[i] = keep & use_depth ? rz : 0.f;
    valid[i] = keep ? 1.f : 0.f;
    n += keep;
  }
  return n;
}

}  // namespace

int DenseAligner::warp(const KeyframeReference::Level& ref, const PyramidLevel& cur,
                       const Eigen::Matrix<float, 3, 4>& t) {
  const int w = cur.k.width, h = cur.k.height;
  const WarpConstants c{t(0, 0), t(0, 1), t(0, 2), t(0, 3), t(1, 0), t(1, 1), t(1, 2), t(1, 3),
                        t(2, 0), t(2, 1), t(2, 2), t(2, 3),
                        static_cast<float>(cur.k.fx), static_cast<float>(cur.k.fy),
                        static_cast<float>(cur.k.cx), static_cast<float>(cur.k.cy),
                        static_cast<float>(w - 1) - 1e-3f, static_cast<float>(h - 1) - 1e-3f,
                        static_cast<float>(params_.min_depth), static_cast<float>(params_.max_depth_step),
                        w, params_.use_depth ? 1.f : 0.f};
  return warpPoints(ref.points.data(), ref.count, cur.intensity.data(), cur.depth.data(), c, res_i_.data(),
                    res_z_.data(), valid_.data());
}

namespace {

// The per-pixel passes of estimateScale() (REKON_SIMD_CLONES: AVX2 lanes and
// FMAs) over all of a level's points: those that do not count have residuals
// 0 and add 0 (log 1 to the likelihood). The sums stay in float lanes, which
// is precise enough for a weighting matrix.
struct SecondMoments {
  float s11 = 0.f, s12 = 0.f, s22 = 0.f;
};

REKON_SIMD_CLONES SecondMoments squareSums(const float* __restrict ri, const float* __restrict rz, int n) {
  float s11 = 0.f, s22 = 0.f;
#pragma omp simd reduction(+ : s11, s22)
  for (int k = 0; k < n; ++k) {
    s11 += ri[k] * ri[k];
    s22 += rz[k] * rz[k];
  }
  return {s11, 0.f, s22};
}

// Sums of w r r^T with w = (nu + 2) / (nu + r^T S^-1 r), S^-1 = [a b; b c] and b2 = 2 b.
REKON_SIMD_CLONES SecondMoments weightedSquareSums(const float* __restrict ri, const float* __restrict rz, int n,
                                                   float a, float b2, float c, float nu) {
  float s11 = 0.f, s12 = 0.f, s22 = 0.f;
#pragma omp simd reduction(+ : s11, s12, s22)
  for (int k = 0; k < n; ++k) {
    const float x = ri[k], y = rz[k];
    const float w = (nu + 2.f) / (nu + a * x * x + b2 * x * y + c * y * y);
    s11 += w * x * x;
    s12 += w * x * y;
    s22 += w * y * y;
  }
  return {s11, s12, s22};
}

// ln x for a finite x >= 1 (ln 1 = 0 exactly), within 1 ulp of std::log
// (measured on 2e7 values): Cephes' logf, as in Eigen's packet log. x = m 2^e
// with m in [sqrt(1/2), sqrt(2)) is taken apart by its bits, and ln m is a
// polynomial. Branch-free, so that GCC vectorises it in an AVX2 clone, where
// std::log is one libm call a pixel and Eigen's packet log is SSE only (Eigen
// picks its packets at compile time).
inline float logAtLeastOne(float x) {
  const auto bits = std::bit_cast<int32_t>(x);
  const float half_to_one = std::bit_cast<float>((bits & 0x007fffff) | 0x3f000000);  // m / 2 in [0.5, 1)
  const float exponent = static_cast<float>((bits >> 23) - 126);
  const bool low = half_to_one < 0.707106781186547524f;
  const float m1 = (low ? half_to_one + half_to_one : half_to_one) - 1.f;
  const float e = low ? exponent - 1.f : exponent;
  float p = 7.0376836292e-2f;  // Horner; written out, as a loop over the coefficients does not vectorise
  p = p * m1 - 1.1514610310e-1f;
  p = p * m1 + 1.1676998740e-1f;
  p = p * m1 - 1.2420140846e-1f;
  p = p * m1 + 1.4249322787e-1f;
  p = p * m1 - 1.6668057665e-1f;
  p = p * m1 + 2.0000714765e-1f;
  p = p * m1 - 2.4999993993e-1f;
  p = p * m1 + 3.3333331174e-1f;
  const float m2 = m1 * m1;
  const float y = m1 * m2 * p + e * -2.12194440e-4f - 0.5f * m2;
  return m1 + y + e * 0.693359375f;
}

// Sum of log(1 + |U r|^2 / nu) over the pixels, in double lanes: the step
// test compares these sums between iterations, so they keep double precision.
REKON_SIMD_CLONES double sumLogQuadratic(const float* __restrict ri, const float* __restrict rz, int n, float u11,
                                         float u12, float u22, float inv_nu) {
  double sum = 0.0;
#pragma omp simd reduction(+ : sum)
  for (int k = 0; k < n; ++k) {
    const float e1 = u11 * ri[k] + u12 * rz[k], e2 = u22 * rz[k];
    sum += static_cast<double>(logAtLeastOne(1.f + inv_nu * (e1 * e1 + e2 * e2)));
  }
  return sum;
}

}  // namespace

double DenseAligner::estimateScale(int count, int n, Scale& scale) {
  const float* ri = res_i_.data();
  const float* rz = res_z_.data();
  const bool use_depth = params_.use_depth;
  const float nu = static_cast<float>(params_.t_dof);
  const double inv_n = 1.0 / n;
  if (scale.s11 <= 0.0) {
    const SecondMoments m = squareSums(ri, rz, count);
    scale.s11 = m.s11 * inv_n;
    scale.s22 = m.s22 * inv_n;
    scale.s12 = 0.0;
  }
  clampScale(scale.s11, scale.s12, scale.s22, use_depth);
  // EM for the scale matrix of the t-distribution (Kerl et al. ICRA 2013):
  // S = mean of w r r^T with w = (nu + 2) / (nu + r^T S^-1 r). Each pass is one
  // fused loop, and the previous iteration's S makes a warm start.
  for (int it = 0; it < kScaleIterations; ++it) {
    const double det = scale.s11 * scale.s22 - scale.s12 * scale.s12;
    const SecondMoments m =
        weightedSquareSums(ri, rz, count, static_cast<float>(scale.s22 / det), static_cast<float>(-2.0 * scale.s12 / det),
                           static_cast<float>(scale.s11 / det), nu);
    Scale next{m.s11 * inv_n, m.s12 * inv_n, m.s22 * inv_n};
    clampScale(next.s11, next.s12, next.s22, use_depth);
    const bool settled = std::abs(next.s11 - scale.s11) <= kScaleTolerance * scale.s11 &&
                         std::abs(next.s22 - scale.s22) <= kScaleTolerance * scale.s22;
    scale = next;
    if (settled) break;
  }
  // Mean negative log-likelihood of the residuals under the t-distribution.
  // With photometric_weight w < 1 it is the objective that accumulate()
  // minimises, so that a step is judged by its own objective: det S =
  // s22 * s11|2 (depth, then intensity given depth, the rows of U) with the
  // intensity factor tempered by w^2 like its whitened residual. Else a step
  // that trades intensity fit for depth fit raises s11 and looks worse.
  const double pw2 = params_.photometric_weight * params_.photometric_weight;
  const double conditional = scale.s11 - scale.s12 * scale.s12 / scale.s22;
  const double log_det = std::log(scale.s22) + pw2 * std::log(conditional);
  const Whitening u = whitening(scale);
  const float inv_nu = static_cast<float>(1.0 / params_.t_dof);
  const double mean_log = sumLogQuadratic(ri, rz, count, u.u11, u.u12, u.u22, inv_nu) * inv_n;
  return 0.5 * log_det + 0.5 * (params_.t_dof + 2.0) * mean_log;
}

DenseAligner::Whitening DenseAligner::whitening(const Scale& scale) const {
  // S^-1 = U^T U with U upper triangular; the photometric row of U weighted.
  const double det = scale.s11 * scale.s22 - scale.s12 * scale.s12;
  const double a = scale.s22 / det, bb = -scale.s12 / det, c = scale.s11 / det;
  const double pw = params_.photometric_weight;
  Whitening u;
  u.u11 = static_cast<float>(pw * std::sqrt(a));
  u.u12 = static_cast<float>(pw * bb / std::sqrt(a));
  u.u22 = params_.use_depth ? static_cast<float>(std::sqrt(std::max(c - bb * bb / a, 0.0))) : 0.f;
  return u;
}

namespace {

// The rows of one block of pixels, column by column (7 columns: 6 Jacobian
// entries and the residual) with the photometric rows of the `count` pixels
// first and their geometric rows after them, and the 28 dot products of
// column pairs added to `sums` (upper triangle). `jacobians` is the block's
// first pixel in the level's planes, `plane` floats apart. One pass over the
// pixels, then contiguous reductions; both vectorise (AVX2 FMAs in the
// clone). A pixel that does not count (valid 0) gets zero rows.
REKON_SIMD_CLONES void accumulateBlock(const float* __restrict res_i, const float* __restrict res_z,
                                       const float* __restrict valid, const float* __restrict jacobians,
                                       int plane, int count, float u11, float u12, float u22, float nu,
                                       float* __restrict block, double sums[7][7]) {
  const int rows = 2 * count;
#pragma omp simd  // independent pixels: the 14 rows a pixel writes never overlap another pixel's
  for (int k = 0; k < count; ++k) {
    const float ri = res_i[k], rz = res_z[k];
    const float e1 = u11 * ri + u12 * rz, e2 = u22 * rz;
    const float sw = valid[k] * std::sqrt((nu + 2.f) / (nu + e1 * e1 + e2 * e2));
    const float s1 = sw * u11, s12 = sw * u12, s2 = sw * u22;
    for (int d = 0; d < 6; ++d) {
      const float ji = jacobians[d * plane + k], jz = jacobians[(6 + d) * plane + k];
      block[d * rows + k] = s1 * ji + s12 * jz;
      block[d * rows + count + k] = s2 * jz;
    }
    block[6 * rows + k] = sw * e1;
    block[6 * rows + count + k] = sw * e2;
  }
  // Column p against all seven columns in one pass: seven independent sums
  // keep the FMA units busy (one sum at a time waits on each FMA's latency),
  // and a row of column p is loaded once. The products with q < p are not
  // needed; they cost less than the stalls they avoid.
  const float *__restrict c0 = block, *__restrict c1 = c0 + rows, *__restrict c2 = c1 + rows,
              *__restrict c3 = c2 + rows, *__restrict c4 = c3 + rows, *__restrict c5 = c4 + rows,
              *__restrict c6 = c5 + rows;
  for (int p = 0; p < 7; ++p) {
    const float* __restrict gp = block + p * rows;
    float d0 = 0.f, d1 = 0.f, d2 = 0.f, d3 = 0.f, d4 = 0.f, d5 = 0.f, d6 = 0.f;
#pragma omp simd reduction(+ : d0, d1, d2, d3, d4, d5, d6)
    for (int r = 0; r < rows; ++r) {
      const float g = gp[r];
      d0 += g * c0[r];
      d1 += g * c1[r];
      d2 += g * c2[r];
      d3 += g * c3[r];
      d4 += g * c4[r];
      d5 += g * c5[r];
      d6 += g * c6[r];
    }
    const float dots[7] = {d0, d1, d2, d3, d4, d5, d6};
    for (int q = p; q < 7; ++q) sums[p][q] += dots[q];
  }
}

}  // namespace

void DenseAligner::accumulate(const KeyframeReference::Level& ref, const Scale& scale, Matrix6d& h, Vector6d& b) {
  // whitening() turns the 2x2-weighted joint residual into two scalar rows
  // sqrt(w) (U J | U r) per pixel, and the 28 dot products of column pairs
  // give J^T W J and J^T W r (accumulateBlock). Float within a block, double
  // across blocks.
  const Whitening u = whitening(scale);
  const float nu = static_cast<float>(params_.t_dof);
  double sums[7][7] = {};
  for (int start = 0; start < ref.count; start += kBlockPixels) {
    const int count = std::min(kBlockPixels, ref.count - start);
    accumulateBlock(res_i_.data() + start, res_z_.data() + start, valid_.data() + start,
                    ref.jacobians.data() + start, ref.count, count, u.u11, u.u12, u.u22, nu, block_.data(), sums);
  }
  Eigen::Matrix<double, 7, 7> total;
  for (int p = 0; p < 7; ++p)
    for (int q = p; q < 7; ++q) total(p, q) = total(q, p) = sums[p][q];
  h = total.topLeftCorner<6, 6>();
  b = total.block<6, 1>(0, 6);
}

AlignResult DenseAligner::align(const KeyframeReference& reference, const RgbdPyramid& current, const Pose& initial,
                                int coarsest, int finest) {
  if (coarsest < 0) coarsest = params_.coarsest_level;
  if (finest < 0) finest = params_.finest_level;
  for (int l = finest; l <= coarsest; ++l) {
    if (!reference.hasLevel(l) || !current.hasLevel(l))
      throw Error("dense alignment on level " + std::to_string(l) +
                  ", which the keyframe or the frame lacks; build both with the aligner's levels");
  }
  AlignResult result;
  result.pose = initial;
  if (!isValidPose(initial, 1e-4)) return result;
  size_t capacity = 0;
  for (int l = finest; l <= coarsest; ++l) capacity = std::max(capacity, static_cast<size_t>(reference.level(l).count));
  if (res_i_.size() < capacity) {
    res_i_.resize(capacity);
    res_z_.resize(capacity);
    valid_.resize(capacity);
  }
  block_.resize(7 * 2 * kBlockPixels);
  result.selected_pixels = reference.level(finest).count;

  Pose t_ck = initial.inverse();
  Scale scale;
  Matrix6d h_final = Matrix6d::Zero();
  bool finest_done = false;
  for (int l = coarsest; l >= finest; --l) {
    const auto& ref = reference.level(l);
    const auto& cur = current.level(l);
    double prev_nll = std::numeric_limits<double>::infinity();
    Pose t_prev = t_ck;
    bool stopped = false;
    for (int it = 0; it < params_.max_iterations; ++it) {
      const Eigen::Matrix<float, 3, 4> t = t_ck.matrix().topRows<3>().cast<float>();
      const int n = warp(ref, cur, t);
      if (n < params_.min_valid_pixels) {
        // The step left too little overlap: the previous estimate is the best this level has.
        t_ck = t_prev;
        stopped = it > 0;
        break;
      }
      const Scale before = scale;
      const double nll = estimateScale(ref.count, n, scale);
      if (nll > prev_nll) {
        t_ck = t_prev;
        scale = before;
        stopped = true;
        break;
      }
      Matrix6d h;
      Vector6d b;
      accumulate(ref, scale, h, b);
      const Vector6d delta = h.ldlt().solve(b);
      if (!delta.allFinite()) {
        t_ck = t_prev;
        break;
      }
      if (l == finest) {
        h_final = h;
        result.valid_pixels = n;
        result.intensity_sigma = std::sqrt(scale.s11);
        result.depth_sigma = params_.use_depth ? std::sqrt(scale.s22) : 0.0;
        finest_done = true;
      }
      t_prev = t_ck;
      prev_nll = nll;
      t_ck = t_ck * expSe3(-delta);
      ++result.iterations;
      if (delta.norm() < params_.convergence_step) {
        stopped = true;
        break;
      }
    }
    if (l == finest) result.converged = stopped;
  }

  const Pose t_kc = orthonormalised(t_ck.inverse());
  if (!isValidPose(t_kc, 1e-6) || !finest_done) return result;
  // h_final is for the left increment exp(xi) * pose (keyframe frame); the
  // adjoint moves it to the right increment in the current camera's frame.
  const Matrix6d ad = adjoint(t_kc);
  const Matrix6d info = ad.transpose() * h_final * ad;
  const double entropy = entropyOfInformation(info);
  if (!std::isfinite(entropy)) return result;
  result.pose = t_kc;
  result.information = 0.5 * (info + info.transpose());
  result.entropy = entropy;
  result.valid = true;
  return result;
}

}  // namespace rekon::tracker
