#pragma once
// Nearest-surface queries against a triangle mesh: a bounding volume
// hierarchy over the triangles (points, when the mesh has none), searched
// within a radius so that points farther than the cap cost little.
#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "rekon/common/mesh.hpp"

namespace rekon::eval {

class ClosestPointIndex {
 public:
  explicit ClosestPointIndex(const Mesh& mesh);
  // Distance from p to the surface, or `radius` when nothing is nearer.
  float distance(const Eigen::Vector3f& p, float radius) const;

 private:
  struct Node {
    Eigen::Vector3f lo = Eigen::Vector3f::Zero(), hi = Eigen::Vector3f::Zero();
    uint32_t first = 0;  // leaf: first primitive; inner: left child (right = left + 1)
    uint32_t count = 0;  // primitives in a leaf; 0 for inner nodes
  };
  struct Prim {
    Eigen::Vector3f a, b, c;  // a point: a = b = c
  };
  void build(uint32_t node, uint32_t first, uint32_t count);

  std::vector<Prim> prims_;
  std::vector<Eigen::Vector3f> centroids_;  // only while building
  std::vector<uint32_t> order_;            // only while building
  std::vector<Node> nodes_;
};

// Squared distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
float pointTriangleDistanceSquared(const Eigen::Vector3f& p, const Eigen::Vector3f& a, const Eigen::Vector3f& b,
                                   const Eigen::Vector3f& c);

}  // namespace rekon::eval
