#include "rekon/tracker/keyframe_reference.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "rekon/common/error.hpp"

namespace rekon::tracker {
namespace {

// Row (a, b, c) of d(residual)/d(point) gives the 6 Jacobian entries for the
// increment exp(xi) p ~ p + v + w x p: d/dv = (a, b, c), d/dw = p x (a, b, c).
inline void twistJacobian(float a, float b, float c, float x, float y, float z, float* j) {
  j[0] = a;
  j[1] = b;
  j[2] = c;
  j[3] = y * c - z * b;
  j[4] = z * a - x * c;
  j[5] = x * b - y * a;
}

void selectLevel(const PyramidLevel& src, const AlignerParams& p, KeyframeReference::Level& out) {
  const Intrinsics& k = src.k;
  const int w = k.width, h = k.height;
  const float fx = static_cast<float>(k.fx), fy = static_cast<float>(k.fy);
  const float cx = static_cast<float>(k.cx), cy = static_cast<float>(k.cy);
  const float min_grad2 = static_cast<float>(p.min_gradient * p.min_gradient);
  // Central differences span two pixels, so the edge test allows twice the step.
  const float max_step = static_cast<float>(2.0 * p.max_depth_step);
  const float* I = src.intensity.data();
  const float* D = src.depth.data();
  // With a pixel budget, raise the gradient threshold to the budget's
  // quantile: the strongest gradients carry most of the information.
  float grad2_threshold = min_grad2;
  if (p.max_pixels_per_level > 0) {
    std::vector<float> grad2;
    grad2.reserve(static_cast<size_t>(w) * h);
    for (int y = 1; y < h - 1; ++y) {
      for (int x = 1; x < w - 1; ++x) {
        const int o = y * w + x;
        if (std::isnan(D[o])) continue;
        const float gx = 0.5f * (I[o + 1] - I[o - 1]), gy = 0.5f * (I[o + w] - I[o - w]);
        if (gx * gx + gy * gy >= min_grad2) grad2.push_back(gx * gx + gy * gy);
      }
    }
    const auto budget = static_cast<size_t>(p.max_pixels_per_level);
    if (grad2.size() > budget) {
      std::nth_element(grad2.begin(), grad2.begin() + (grad2.size() - budget), grad2.end());
      grad2_threshold = std::max(min_grad2, grad2[grad2.size() - budget]);
    }
  }
  constexpr int kRows = KeyframeReference::kJacobianRows;
  out.k = k;
  out.points.clear();
  out.points.reserve(static_cast<size_t>(w) * h * KeyframeReference::kPointStride / 2);
  std::vector<float> rows;  // pixel by pixel, laid out as planes at the end
  rows.reserve(static_cast<size_t>(w) * h * kRows / 2);
  for (int y = 1; y < h - 1; ++y) {
    for (int x = 1; x < w - 1; ++x) {
      const int o = y * w + x;
      const float z = D[o];
      const float zl = D[o - 1], zr = D[o + 1], zu = D[o - w], zd = D[o + w];
      if (std::isnan(z + zl + zr + zu + zd)) continue;
      if (std::abs(zr - zl) > max_step * z || std::abs(zd - zu) > max_step * z) continue;
      // Depth gradients from a 3x3 Sobel stencil where all of it is valid:
      // sensor depth is noisy and quantised, and the geometric Jacobian
      // inherits that noise; central differences only where it is not.
      float zgx = 0.5f * (zr - zl), zgy = 0.5f * (zd - zu);
      const float zul = D[o - w - 1], zur = D[o - w + 1], zdl = D[o + w - 1], zdr = D[o + w + 1];
      if (!std::isnan(zul + zur + zdl + zdr)) {
        const float sx = 0.125f * (zur + 2.f * zr + zdr - zul - 2.f * zl - zdl);
        const float sy = 0.125f * (zdl + 2.f * zd + zdr - zul - 2.f * zu - zur);
        if (std::abs(sx) <= 0.5f * max_step * z && std::abs(sy) <= 0.5f * max_step * z) {
          zgx = sx;
          zgy = sy;
        }
      }
      const float gx = 0.5f * (I[o + 1] - I[o - 1]), gy = 0.5f * (I[o + w] - I[o - w]);
      if (gx * gx + gy * gy < grad2_threshold) continue;
      const float px = (static_cast<float>(x) - cx) * z / fx;
      const float py = (static_cast<float>(y) - cy) * z / fy;
      out.points.insert(out.points.end(), {px, py, z, I[o]});
      float j[kRows];
      const float iz = 1.f / z;
      // Photometric: grad(I) * d(projection)/d(point).
      const float a = gx * fx * iz, b = gy * fy * iz;
      twistJacobian(a, b, -(a * px + b * py) * iz, px, py, z, j);
      // Geometric: grad(Z) * d(projection)/d(point) minus d(point z)/d(point).
      const float ad = zgx * fx * iz, bd = zgy * fy * iz;
      twistJacobian(ad, bd, -(ad * px + bd * py) * iz - 1.f, px, py, z, j + 6);
      rows.insert(rows.end(), j, j + kRows);
    }
  }
  out.count = static_cast<int>(out.points.size() / KeyframeReference::kPointStride);
  out.points.shrink_to_fit();
  out.jacobians.assign(static_cast<size_t>(kRows) * out.count, 0.f);
  for (int i = 0; i < out.count; ++i)
    for (int r = 0; r < kRows; ++r) out.jacobians[static_cast<size_t>(r) * out.count + i] = rows[static_cast<size_t>(kRows) * i + r];
}

}  // namespace

KeyframeReference::KeyframeReference(const RgbdPyramid& pyramid, const AlignerParams& params)
    : finest_(params.finest_level), coarsest_(std::max(params.coarsest_level, pyramid.coarsestLevel())) {
  levels_.resize(coarsest_ + 1);
  for (int l = finest_; l <= coarsest_; ++l) selectLevel(pyramid.level(l), params, levels_[l]);
}

const KeyframeReference::Level& KeyframeReference::level(int l) const {
  if (!hasLevel(l))
    throw Error("keyframe reference has no level " + std::to_string(l) + " (levels " + std::to_string(finest_) +
                ".." + std::to_string(coarsest_) + "); build it with the aligner's levels");
  return levels_[l];
}

}  // namespace rekon::tracker
