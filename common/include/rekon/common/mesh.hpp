#pragma once
// A colored triangle mesh and its PLY input/output (binary little-endian out;
// binary or ASCII in), readable by MeshLab and Open3D.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

namespace rekon {

struct Mesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<std::array<uint8_t, 3>> colors;  // RGB per vertex; empty = uncolored
  std::vector<Eigen::Vector3i> triangles;
};

// Appends `piece`, whose triangles index `to`'s vertices and then its own (a PlyWriter piece).
void appendMesh(Mesh& to, const Mesh& piece);

void writePly(const Mesh& mesh, const std::string& path);

// A PLY file written as its mesh arrives in pieces, never holding all of it:
// vertices and faces go to two files beside PATH, which finish() joins
// behind the header into PATH.tmp and renames over PATH (a killed writer
// leaves the previous file). Throws rekon::Error naming PATH when it cannot.
class PlyWriter {
 public:
  PlyWriter(std::string path, bool colored);
  ~PlyWriter();  // removes the files beside PATH that finish() did not
  PlyWriter(const PlyWriter&) = delete;
  PlyWriter& operator=(const PlyWriter&) = delete;
  // piece.triangles index every vertex added so far, this piece's after the earlier pieces'.
  void add(const Mesh& piece);
  void finish();
  int64_t vertices() const { return vertices_; }
  int64_t faces() const { return faces_; }

 private:
  void closeParts();
  std::string path_;
  bool colored_;
  std::FILE* vertex_out_;
  std::FILE* face_out_;
  int64_t vertices_ = 0, faces_ = 0;
};
// Throws rekon::Error naming the file for anything it cannot read.
Mesh readPly(const std::string& path);

}  // namespace rekon
