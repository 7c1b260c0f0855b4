#pragma once
// A colored triangle mesh and its PLY input/output (binary little-endian out;
// binary or ASCII in), readable by MeshLab and Open3D.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace rekon {

struct Mesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<std::array<uint8_t, 3>> colors;  // RGB per vertex; empty = uncolored
  std::vector<Eigen::Vector3i> triangles;
};

void writePly(const Mesh& mesh, const std::string& path);
// Throws rekon::Error naming the file for anything it cannot read.
Mesh readPly(const std::string& path);

}  // namespace rekon
