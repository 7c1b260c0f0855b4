#include "closest_point.hpp"

#include <algorithm>
#include <cmath>

namespace rekon::eval {
namespace {

constexpr uint32_t kLeafSize = 4;

float boxDistanceSquared(const Eigen::Vector3f& p, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
  const Eigen::Vector3f d = (lo - p).cwiseMax(p - hi).cwiseMax(Eigen::Vector3f::Zero());
  return d.squaredNorm();
}

}  // namespace

float pointTriangleDistanceSquared(const Eigen::Vector3f& p, const Eigen::Vector3f& a, const Eigen::Vector3f& b,
                                   const Eigen::Vector3f& c) {
  const Eigen::Vector3f ab = b - a, ac = c - a, ap = p - a;
  const float d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return ap.squaredNorm();
  const Eigen::Vector3f bp = p - b;
  const float d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return bp.squaredNorm();
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    const float v = d1 / (d1 - d3);
    return (ap - v * ab).squaredNorm();
  }
  const Eigen::Vector3f cp = p - c;
  const float d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return cp.squaredNorm();
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    const float w = d2 / (d2 - d6);
    return (ap - w * ac).squaredNorm();
  }
  const float va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const float w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return (bp - w * (c - b)).squaredNorm();
  }
  const float denom = 1.0f / (va + vb + vc);
  const float v = vb * denom, w = vc * denom;
  return (ap - ab * v - ac * w).squaredNorm();
}

ClosestPointIndex::ClosestPointIndex(const Mesh& mesh) {
  if (!mesh.triangles.empty()) {
    prims_.reserve(mesh.triangles.size());
    for (const auto& t : mesh.triangles) {
      prims_.push_back({mesh.vertices[static_cast<size_t>(t[0])], mesh.vertices[static_cast<size_t>(t[1])],
                        mesh.vertices[static_cast<size_t>(t[2])]});
    }
  } else {
    prims_.reserve(mesh.vertices.size());
    for (const auto& v : mesh.vertices) prims_.push_back({v, v, v});
  }
  if (prims_.empty()) return;
  centroids_.reserve(prims_.size());
  for (const auto& p : prims_) centroids_.push_back((p.a + p.b + p.c) / 3.0f);
  order_.resize(prims_.size());
  for (uint32_t i = 0; i < order_.size(); ++i) order_[i] = i;
  nodes_.reserve(2 * prims_.size() / kLeafSize + 2);
  nodes_.push_back({});
  build(0, 0, static_cast<uint32_t>(prims_.size()));
  std::vector<Prim> sorted(prims_.size());
  for (size_t i = 0; i < order_.size(); ++i) sorted[i] = prims_[order_[i]];
  prims_ = std::move(sorted);
  centroids_ = {};
  order_ = {};
}

// Fills nodes_[node] for order_[first, first + count): a leaf, or a median
// split on the longest axis of the centroid bounds with two new children.
void ClosestPointIndex::build(uint32_t node, uint32_t first, uint32_t count) {
  Eigen::Vector3f lo = prims_[order_[first]].a, hi = lo, clo = centroids_[order_[first]], chi = clo;
  for (uint32_t i = first; i < first + count; ++i) {
    const Prim& p = prims_[order_[i]];
    lo = lo.cwiseMin(p.a).cwiseMin(p.b).cwiseMin(p.c);
    hi = hi.cwiseMax(p.a).cwiseMax(p.b).cwiseMax(p.c);
    clo = clo.cwiseMin(centroids_[order_[i]]);
    chi = chi.cwiseMax(centroids_[order_[i]]);
  }
  nodes_[node].lo = lo;
  nodes_[node].hi = hi;
  if (count <= kLeafSize) {
    nodes_[node].first = first;
    nodes_[node].count = count;
    return;
  }
  int axis = 0;
  const Eigen::Vector3f ext = chi - clo;
  if (ext.y() > ext.x()) axis = 1;
  if (ext.z() > ext[axis]) axis = 2;
  const uint32_t half = count / 2;
  std::nth_element(order_.begin() + first, order_.begin() + first + half, order_.begin() + first + count,
                   [&](uint32_t a, uint32_t b) { return centroids_[a][axis] < centroids_[b][axis]; });
  const uint32_t left = static_cast<uint32_t>(nodes_.size());
  nodes_.push_back({});
  nodes_.push_back({});
  nodes_[node].first = left;
  nodes_[node].count = 0;
  build(left, first, half);
  build(left + 1, first + half, count - half);
}

float ClosestPointIndex::distance(const Eigen::Vector3f& p, float radius) const {
  float best = radius * radius;
  if (prims_.empty()) return radius;
  uint32_t stack[64];
  int top = 0;
  if (boxDistanceSquared(p, nodes_[0].lo, nodes_[0].hi) < best) stack[top++] = 0;
  while (top > 0) {
    const Node& n = nodes_[stack[--top]];
    if (boxDistanceSquared(p, n.lo, n.hi) >= best) continue;
    if (n.count > 0) {
      for (uint32_t i = n.first; i < n.first + n.count; ++i) {
        const Prim& t = prims_[i];
        best = std::min(best, pointTriangleDistanceSquared(p, t.a, t.b, t.c));
      }
      continue;
    }
    // Visit the nearer child first: push it last.
    const float dl = boxDistanceSquared(p, nodes_[n.first].lo, nodes_[n.first].hi);
    const float dr = boxDistanceSquared(p, nodes_[n.first + 1].lo, nodes_[n.first + 1].hi);
    if (dl < dr) {
      if (dr < best) stack[top++] = n.first + 1;
      if (dl < best) stack[top++] = n.first;
    } else {
      if (dl < best) stack[top++] = n.first;
      if (dr < best) stack[top++] = n.first + 1;
    }
  }
  return std::sqrt(best);
}

}  // namespace rekon::eval
