// The house rule (messages <- common <- services <- tools) on the real tree,
// and the checker itself on a planted tree with each kind of coupling that
// once crept into rekon, so the rule cannot silently erode.
#include <gtest/gtest.h>

#include <cstdio>
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

// A planted file: "#include" lines, quoted but for those written "<...>".
void write(const std::string& root, const std::string& file, const std::vector<std::string>& includes) {
  fs::create_directories(fs::path(root + "/" + file).parent_path());
  std::ofstream out(root + "/" + file);
  for (const auto& i : includes) out << "#include " << (i.front() == '<' ? i : "\"" + i + "\"") << "\n";
  out << "#include <vector>\n";
}

void writeText(const std::string& root, const std::string& file, const std::string& text) {
  fs::create_directories(fs::path(root + "/" + file).parent_path());
  std::ofstream(root + "/" + file) << text;
}

// What the check of the tree (messages, common, cuda, services) saw when these
// bounds were set: 179 sources, 497 includes of tree files, 53 links between
// rekon targets. The bounds are two thirds of each: room for the tree to
// shrink by refactoring, none for a check that silently reads little or
// nothing (a moved folder, a broken pattern).
constexpr size_t kMinFiles = 119;
constexpr size_t kMinTreeIncludes = 331;
constexpr size_t kMinTreeLinks = 35;

TEST(Layers, TheTreeKeepsTheRule) {
  const Scan s = scan(test::sourceDir());
  std::string list;
  for (const auto& v : s.violations) list += "  " + v.str() + "\n";
  EXPECT_TRUE(s.violations.empty()) << s.violations.size()
                                    << " includes or links break messages <- common <- services <- tools:\n"
                                    << list;
  std::printf("scanned %zu sources, %zu includes of tree files, %zu links between rekon targets\n", s.files,
              s.tree_includes, s.tree_links);
  EXPECT_GE(s.files, kMinFiles);
  EXPECT_GE(s.tree_includes, kMinTreeIncludes);
  EXPECT_GE(s.tree_links, kMinTreeLinks);
}

TEST(Layers, AnEmptyTreeIsNoProof) {
  test::TempDir dir;
  const Scan s = scan(dir.path());
  EXPECT_TRUE(s.violations.empty());
  EXPECT_LT(s.files, kMinFiles);  // so TheTreeKeepsTheRule would fail on it
  EXPECT_EQ(s.tree_includes + s.tree_links, 0u);
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
  write(r, "services/viewer/src/viewer.cpp", {"<rekon/optimiser/graph_update_filter.hpp>", "<rekon/common/pose.hpp>"});

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
      "services/viewer/src/viewer.cpp -> services/optimiser",
  };
  EXPECT_EQ(found, expected);
}

TEST(Layers, EveryKindOfCMakeLinkIsFound) {
  test::TempDir dir;
  const std::string r = dir.path();
  writeText(r, "messages/CMakeLists.txt", "add_library(rekon_messages INTERFACE)\ntarget_link_libraries(rekon_messages INTERFACE lcm::lcm rekon_common)\n");
  writeText(r, "common/CMakeLists.txt",
            "add_library(rekon_common STATIC x.cpp)  # links rekon_tracker in a comment: not a link\n"
            "target_link_libraries(rekon_common\n  PUBLIC Eigen3::Eigen rekon_messages\n  PRIVATE rekon_tracker)\n");
  writeText(r, "cuda/CMakeLists.txt", "add_library(rekon_volume_cuda STATIC v.cu)\n"
                                       "target_link_libraries(rekon_volume_cuda PUBLIC rekon_volume_kernels rekon_volume)\n");
  writeText(r, "services/mapper/CMakeLists.txt",
            "add_library(rekon_volume_kernels INTERFACE)\nadd_library(rekon_volume STATIC v.cpp)\n"
            "target_link_libraries(rekon_volume PUBLIC rekon_common rekon_volume_kernels PRIVATE rekon_volume_cuda \"rekon_optimiser\")\n"
            "rekon_add_service_node(mapper LIBS Threads::Threads rekon_synth)\n");
  writeText(r, "services/optimiser/CMakeLists.txt", "add_library(rekon_optimiser STATIC o.cpp)\n"
                                                      "target_link_libraries(rekon_optimiser PUBLIC rekon_common)\n");
  writeText(r, "services/tracker/CMakeLists.txt", "add_library(rekon_tracker STATIC t.cpp)\nrekon_add_service_node(tracker)\n"
                                                    "target_link_libraries(rekon-tracker PRIVATE rekon_test_support)\n");
  writeText(r, "tools/synth/CMakeLists.txt", "add_library(rekon_synth STATIC s.cpp)\n"
                                               "target_link_libraries(rekon_synth PUBLIC rekon_tracker rekon_volume)\n");
  writeText(r, "tests/CMakeLists.txt", "add_library(rekon_test_support STATIC t.cpp)\n"
                                         "target_link_libraries(rekon_test_support PUBLIC rekon_optimiser)\n");

  std::set<std::string> found;
  for (const auto& v : violations(r)) found.insert(v.file + ": " + v.target + " -> " + v.include);
  const std::set<std::string> expected = {
      "messages/CMakeLists.txt: rekon_messages -> rekon_common",
      "common/CMakeLists.txt: rekon_common -> rekon_tracker",
      "cuda/CMakeLists.txt: rekon_volume_cuda -> rekon_volume",
      "services/mapper/CMakeLists.txt: rekon_volume -> rekon_optimiser",
      "services/mapper/CMakeLists.txt: rekon_mapper_node -> rekon_synth",
      "services/tracker/CMakeLists.txt: rekon-tracker -> rekon_test_support",
  };
  EXPECT_EQ(found, expected);
  EXPECT_EQ(scan(r).tree_links, 15u);  // every link between two targets above, allowed or not
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
