// writeSequence and `rekon synth`: files on disk in TUM layout.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <sstream>

#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/synth/synth.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;

namespace {

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

rekon::synth::SequenceOptions tabletop(int frames, uint64_t seed) {
  rekon::synth::SequenceOptions o;
  o.scene = "tabletop";
  o.frames = frames;
  o.seed = seed;
  return o;
}

TEST(SynthSequence, SameSeedGivesIdenticalFiles) {
  rekon::test::TempDir a, b, c;
  rekon::synth::writeSequence(tabletop(3, 11), a.path());
  rekon::synth::writeSequence(tabletop(3, 11), b.path());
  rekon::synth::writeSequence(tabletop(3, 12), c.path());
  size_t files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(a.path())) {
    if (!entry.is_regular_file()) continue;
    const fs::path rel = fs::relative(entry.path(), a.path());
    ASSERT_TRUE(fs::exists(fs::path(b.path()) / rel)) << rel;
    EXPECT_EQ(slurp(entry.path()), slurp(fs::path(b.path()) / rel)) << rel;
    ++files;
  }
  EXPECT_EQ(files, 3u * 2 + 5);  // rgb + depth per frame; rgb.txt depth.txt groundtruth.txt camera.yaml mesh_gt.ply
  EXPECT_NE(slurp(fs::path(a.path()) / "rgb/0.000000.png"), slurp(fs::path(c.path()) / "rgb/0.000000.png"));
}

TEST(SynthSequence, WritesATumDatasetWithGroundTruthAndMesh) {
  rekon::test::TempDir dir;
  auto o = tabletop(4, 1);
  o.noise = rekon::synth::Noise::None;
  o.drift_translation_per_m = 0.01;
  o.drift_rotation_deg_per_m = 0.5;
  const auto report = rekon::synth::writeSequence(o, dir.path());
  EXPECT_EQ(report.frames, 4);
  const rekon::TumDataset ds(dir.path());
  ASSERT_EQ(ds.size(), 4u);
  ASSERT_TRUE(ds.hasGroundTruth());
  EXPECT_EQ(ds.groundTruth().size(), 4u);
  EXPECT_DOUBLE_EQ(ds.intrinsics().depth_scale, 5000.0);
  const auto frame = ds.load(3);
  EXPECT_EQ(frame.depth.cols, 640);
  EXPECT_GT(cv::countNonZero(frame.depth), 640 * 480 * 9 / 10);
  EXPECT_EQ(rekon::readTumTrajectory(dir / "drifted_trajectory.txt").size(), 4u);
  const rekon::Mesh mesh = rekon::readPly(dir / "mesh_gt.ply");
  EXPECT_EQ(mesh.vertices.size(), report.mesh_vertices);
  EXPECT_EQ(mesh.colors.size(), mesh.vertices.size());
}

// The cache of a long scan (rekon bench longrun --dataset): color as JPEG,
// depth as the same PNG, read back by the dataset reader the services use.
TEST(SynthSequence, JpegColorTakesAFractionOfThePngsBytesAndReadsBackCloseToIt) {
  rekon::test::TempDir png, jpeg;
  rekon::synth::writeSequence(tabletop(3, 5), png.path());
  auto o = tabletop(3, 5);
  o.jpeg_quality = 95;
  rekon::synth::writeSequence(o, jpeg.path());
  EXPECT_NE(slurp(jpeg / "rgb.txt").find("rgb/0.066667.jpg"), std::string::npos);
  const rekon::TumDataset a(png.path()), b(jpeg.path());
  ASSERT_EQ(b.size(), 3u);
  double png_bytes = 0, jpeg_bytes = 0;
  for (size_t i = 0; i < 3; ++i) {
    const rekon::RgbdFrame fa = a.load(i), fb = b.load(i);
    EXPECT_EQ(cv::norm(fa.depth, fb.depth, cv::NORM_INF), 0.0) << i;
    // Measured 2.15-2.17 levels a channel on average (bound 3), 25-27 at
    // most: the sensor noise's own sigma is 2.5 levels.
    EXPECT_LT(cv::norm(fa.color, fb.color, cv::NORM_L1) / (640.0 * 480 * 3), 3.0) << i;
    const rekon::EncodedFrame ea = a.loadEncoded(i), eb = b.loadEncoded(i);
    EXPECT_EQ(eb.color_format, "jpeg");
    png_bytes += static_cast<double>(ea.color.size());
    jpeg_bytes += static_cast<double>(eb.color.size());
  }
  EXPECT_LT(jpeg_bytes, png_bytes / 4) << jpeg_bytes << " " << png_bytes;  // measured 1 / 5.5
  o.jpeg_quality = 101;
  rekon::test::TempDir bad;
  EXPECT_THROW(rekon::synth::writeSequence(o, bad.path()), rekon::Error);
}

TEST(SynthCommand, WritesTheSequenceAndEndsWithKeyValues) {
  rekon::test::TempDir dir;
  std::string out;
  const int rc = rekon::test::runCommand(rekon::test::binDir() + "/rekon synth --scene tabletop --frames 2 --noise none --out " +
                                             dir.path() + "/seq",
                                         &out);
  ASSERT_EQ(rc, 0) << out;
  EXPECT_NE(out.find("frames=2 "), std::string::npos) << out;
  EXPECT_TRUE(fs::exists(dir / "seq/rgb.txt"));
  EXPECT_FALSE(fs::exists(dir / "seq/drifted_trajectory.txt"));
}

TEST(SynthCommand, RejectsAMalformedDrift) {
  rekon::test::TempDir dir;
  std::string out;
  const int rc = rekon::test::runCommand(rekon::test::binDir() + "/rekon synth --scene tabletop --frames 1 --drift 0.01 --out " +
                                             dir.path(),
                                         &out);
  EXPECT_NE(rc, 0);
  EXPECT_NE(out.find("T_PER_M,R_DEG_PER_M"), std::string::npos) << out;
}

}  // namespace
