#include <gtest/gtest.h>

#include <fstream>

#include "rekon/common/error.hpp"
#include "rekon/common/mesh.hpp"
#include "test_support.hpp"

TEST(Mesh, BinaryPlyRoundTripsWithColors) {
  rekon::test::TempDir dir;
  rekon::Mesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  m.colors = {{{255, 0, 0}}, {{0, 255, 0}}, {{0, 0, 255}}, {{9, 9, 9}}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  rekon::writePly(m, dir / "m.ply");
  const auto r = rekon::readPly(dir / "m.ply");
  ASSERT_EQ(r.vertices.size(), 4u);
  ASSERT_EQ(r.colors.size(), 4u);
  ASSERT_EQ(r.triangles.size(), 2u);
  EXPECT_EQ(r.vertices[3], m.vertices[3]);
  EXPECT_EQ(r.colors[2], m.colors[2]);
  EXPECT_EQ(r.triangles[1], m.triangles[1]);
}

TEST(Mesh, AsciiPlyWithQuadsIsTriangulated) {
  rekon::test::TempDir dir;
  std::ofstream(dir / "q.ply") << "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                                  "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                                  "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
  const auto r = rekon::readPly(dir / "q.ply");
  EXPECT_EQ(r.triangles.size(), 2u);
}

TEST(Mesh, TruncatedPlyIsAnError) {
  rekon::test::TempDir dir;
  std::ofstream(dir / "t.ply", std::ios::binary) << "ply\nformat binary_little_endian 1.0\nelement vertex 10\n"
                                                    "property float x\nproperty float y\nproperty float z\nend_header\n1234";
  EXPECT_THROW(rekon::readPly(dir / "t.ply"), rekon::Error);
}
