// The house rule (messages <- common <- services <- tools) on the real tree,
// and the checker itself on a planted tree with each kind of coupling that
// once crept into rekon, so the rule cannot silently erode.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include "layers.hpp"
#include "test_support.hpp"

namespace rekon::architecture {
namespace {
namespace fs = std::filesystem;

void write(const std::string& root, const std::string& file, const std::vector<std::string>& includes) {
  fs::create_directories(fs::path(root + "/" + file).parent_path());
  std::ofstream out(root + "/" + file);
  for (const auto& i : includes) out << "#include \"" << i << "\"\n";
  out << "#include <vector>\n";
}

TEST(Layers, TheTreeKeepsTheRule) {
  const auto found = violations(test::sourceDir());
  std::string list;
  for (const auto& v : found) list += "  " + v.str() + "\n";
  EXPECT_TRUE(found.empty()) << found.size() << " includes break messages <- common <- services <- tools:\n" << list;
}

TEST(Layers, EveryKindOfCouplingIsFound) {
  test::TempDir dir;
  const std::string r = dir.path();
  // The headers the planted files reach for.
  write(r, "common/include/rekon/common/pose.hpp", {});
  write(r, "services/optimiser/include/rekon/optimiser/graph_update_filter.hpp", {});
  write(r, "services/tracker/include/rekon/tracker/tracker.hpp", {"rekon/common/pose.hpp", "rekon_msgs/frame_t.hpp"});
  write(r, "services/mapper/store/include/rekon/store/keyframe_store.hpp", {});
  write(r, "services/mapper/volume/include/rekon/volume/volume_kernels.hpp", {"rekon/common/pose.hpp"});
  write(r, "services/mapper/volume/include/rekon/volume/tsdf_volume.hpp", {"volume_kernels.hpp"});
  write(r, "tools/synth/include/rekon/synth/synth.hpp", {"rekon/tracker/tracker.hpp", "rekon/store/keyframe_store.hpp"});
  // Each of these breaks the rule once.
  write(r, "services/mapper/service/src/mapper_service.cpp", {"rekon/optimiser/graph_update_filter.hpp", "rekon/store/keyframe_store.hpp"});
  write(r, "services/mapper/bench/src/bench_data.cpp", {"rekon/tracker/tracker.hpp", "rekon/synth/synth.hpp"});
  write(r, "services/player/src/player.cpp", {"rekon/store/keyframe_store.hpp", "rekon/common/pose.hpp"});
  write(r, "common/src/pose.cpp", {"rekon/tracker/tracker.hpp", "rekon/common/pose.hpp"});
  write(r, "cuda/volume/volume_cuda.cu", {"rekon/volume/volume_kernels.hpp", "rekon/volume/tsdf_volume.hpp", "rekon/common/pose.hpp"});
  write(r, "messages/x.hpp", {"rekon/common/pose.hpp"});

  std::set<std::string> found;
  for (const auto& v : violations(r)) found.insert(v.file + " -> " + v.owner);
  const std::set<std::string> expected = {
      "services/mapper/bench/src/bench_data.cpp -> services/tracker",
      "services/mapper/bench/src/bench_data.cpp -> tools",
      "services/mapper/service/src/mapper_service.cpp -> services/optimiser",
      "services/player/src/player.cpp -> services/mapper",
      "common/src/pose.cpp -> services/tracker",
      "cuda/volume/volume_cuda.cu -> services/mapper",
      "messages/x.hpp -> common",
  };
  EXPECT_EQ(found, expected);
}

TEST(Layers, NoServiceHeaderParsesACommandLine) {
  std::string list;
  for (const auto& f : headersWithCommandLines(test::sourceDir())) list += "  " + f + "\n";
  EXPECT_EQ(list, "") << "service headers with a command-line entry point (tools own their commands):\n" << list;
  test::TempDir dir;
  write(dir.path(), "services/tracker/include/rekon/tracker/odometry_command.hpp", {});
  std::ofstream(dir / "services/tracker/include/rekon/tracker/odometry_command.hpp", std::ios::app)
      << "int odometryMain(int argc, char** argv);\n";
  write(dir.path(), "services/tracker/src/main_helpers.cpp", {});  // a source, not the API: not looked at
  EXPECT_EQ(headersWithCommandLines(dir.path()),
            std::vector<std::string>{"services/tracker/include/rekon/tracker/odometry_command.hpp"});
}

TEST(Layers, LayerOfAPath) {
  EXPECT_EQ(layerOf("services/mapper/volume/src/x.cpp"), "services/mapper");
  EXPECT_EQ(layerOf("common/include/rekon/common/pose.hpp"), "common");
  EXPECT_EQ(layerOf("tools/cli/main.cpp"), "tools");
  EXPECT_EQ(layerOf("README.md"), "");
}

}  // namespace
}  // namespace rekon::architecture
