// `rekon fuse` (issue 6, section 4) on a few frames of a synthetic sequence.
#include <gtest/gtest.h>

#include <filesystem>
#include <regex>

#include "commands.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/synth/synth.hpp"
#include "test_support.hpp"

namespace {

int runFuse(std::vector<std::string> args) {
  args.insert(args.begin(), "rekon fuse");
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  return rekon::fuseCommand(static_cast<int>(argv.size()), argv.data());
}

TEST(FuseCommand, WritesAMeshAndEndsWithTheSpeedLine) {
  rekon::test::TempDir dir;
  rekon::synth::SequenceOptions options;
  options.scene = "tabletop";
  options.frames = 4;
  options.noise = rekon::synth::Noise::None;
  rekon::synth::writeSequence(options, dir / "seq");

  testing::internal::CaptureStdout();
  const int status = runFuse({"--dataset", dir / "seq", "--poses", dir / "seq/groundtruth.txt", "--out", dir / "mesh.ply",
                              "--frames", "3"});
  const std::string out = testing::internal::GetCapturedStdout();
  EXPECT_EQ(status, 0);
  EXPECT_TRUE(std::regex_search(out, std::regex(R"(ms_per_frame=[0-9.]+ blocks=[1-9][0-9]* bytes_per_voxel=12\n$)"))) << out;
  const rekon::Mesh mesh = rekon::readPly(dir / "mesh.ply");
  EXPECT_GT(mesh.triangles.size(), 1000u);
  EXPECT_EQ(mesh.colors.size(), mesh.vertices.size());
}

TEST(FuseCommand, PosesThatMatchNoFrameAreAnError) {
  rekon::test::TempDir dir;
  rekon::synth::SequenceOptions options;
  options.scene = "tabletop";
  options.frames = 2;
  options.noise = rekon::synth::Noise::None;
  rekon::synth::writeSequence(options, dir / "seq");
  rekon::writeTumTrajectory({{1000.0, rekon::Pose::Identity()}}, dir / "far.txt");
  EXPECT_THROW(runFuse({"--dataset", dir / "seq", "--poses", dir / "far.txt", "--out", dir / "m.ply"}), rekon::Error);
}

}  // namespace
