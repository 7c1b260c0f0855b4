#include <gtest/gtest.h>

#include <filesystem>
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

TEST(Mesh, APlyWrittenInPiecesLeavesTheOldFileUntilFinishAndNamesAFolderItCannotWriteTo) {
  rekon::test::TempDir dir;
  const std::string path = dir / "m.ply";
  rekon::Mesh first;
  first.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  first.colors = {{{1, 2, 3}}, {{4, 5, 6}}, {{7, 8, 9}}};
  first.triangles = {{0, 1, 2}};
  rekon::writePly(first, path);
  rekon::Mesh second;  // its triangle uses the first piece's vertices 1 and 2
  second.vertices = {{1, 1, 0}};
  second.colors = {{{10, 11, 12}}};
  second.triangles = {{1, 3, 2}};
  {
    rekon::PlyWriter ply(path, true);
    ply.add(first);
    ply.add(second);
    EXPECT_EQ(rekon::readPly(path).vertices.size(), 3u) << "the old file stays until finish()";
    ply.finish();
    EXPECT_EQ(ply.vertices(), 4);
  }
  const rekon::Mesh r = rekon::readPly(path);
  ASSERT_EQ(r.vertices.size(), 4u);
  EXPECT_EQ(r.colors[3], second.colors[0]);
  ASSERT_EQ(r.triangles.size(), 2u);
  EXPECT_EQ(r.triangles[1], second.triangles[0]);
  {
    rekon::PlyWriter abandoned(dir / "gone.ply", true);  // never finished: nothing is left behind
    abandoned.add(first);
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "gone.ply") || std::filesystem::exists(dir / "gone.ply.vertices.tmp"));
  try {
    rekon::PlyWriter ply(dir / "no_such_folder/m.ply", true);
    FAIL() << "a folder that does not exist must throw";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("no_such_folder/m.ply"), std::string::npos) << e.what();
  }
}
