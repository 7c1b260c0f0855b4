// The page in a real browser: Debian's chromium, headless, opens rekon-viewer
// (the built binary, in this test's network namespace) while mesh blocks
// arrive on the bus, and the test reads what the page itself counted (its
// <body data-*> counters, through --dump-dom) and looks at its screenshot.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <regex>
#include <thread>

#include "rekon/common/bus.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "test_support.hpp"
#include "viewer_test_support.hpp"

namespace rekon::viewer {
namespace {

using rekon::test::binDir;
using rekon::test::readText;
using rekon::test::runCommand;
using Clock = std::chrono::steady_clock;

bool haveChromium() { return runCommand("command -v chromium") == 0; }

// Headless chromium with software WebGL (SwiftShader): no GPU and no display needed.
std::string chromium(const std::string& profile) {
  return "timeout 60 chromium --headless=new --no-sandbox --disable-dev-shm-usage --use-angle=swiftshader "
         "--enable-unsafe-swiftshader --hide-scrollbars --user-data-dir=" + profile + " --window-size=1280,800 ";
}

// The URL rekon-viewer logs once it listens; "" when it did not within `seconds`.
std::string waitForUrl(const std::string& log, double seconds) {
  const std::regex url_line(R"(viewer: (http://127\.0\.0\.1:[0-9]+/))");
  const auto start = Clock::now();
  while (test::secondsSince(start) < seconds) {
    std::smatch m;
    const std::string text = readText(log);
    if (std::regex_search(text, m, url_line)) return m[1];
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return "";
}

long long dataCounter(const std::string& dom, const std::string& name) {
  std::smatch m;
  if (!std::regex_search(dom, m, std::regex("data-" + name + "=\"([0-9]+)\""))) return -1;
  return std::stoll(m[1]);
}

// Pixels that differ from the page's background (#1e2328) outside the status panel.
int drawnPixels(const std::string& png) {
  const cv::Mat image = cv::imread(png, cv::IMREAD_COLOR);
  if (image.empty()) return -1;
  int drawn = 0;
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) {
      if (x < 500 && y < 300) continue;  // the panel
      const cv::Vec3b p = image.at<cv::Vec3b>(y, x);  // BGR
      drawn += std::abs(p[0] - 0x28) + std::abs(p[1] - 0x23) + std::abs(p[2] - 0x1e) > 30;
    }
  }
  return drawn;
}

// A 20 x 20 wall of blocks (8 cm each) in front of the camera's start, 24 triangles per block.
std::vector<BlockMesh> wall(int64_t version) {
  std::vector<BlockMesh> blocks;
  for (int y = -10; y < 10; ++y) {
    for (int x = -10; x < 10; ++x) blocks.push_back(test::syntheticBlock({x, y, 20}, version, 24));
  }
  return blocks;
}

void publish(Bus& bus, const std::vector<BlockMesh>& blocks, int64_t sequence) {
  MeshBlocksParams params;
  params.voxel_size = 0.01;
  params.block_voxels = 8;
  for (const auto& m : encodeMeshBlocks(blocks, params, sequence, false)) bus.publish(channel::kMeshBlocks, m);
}

// The wall published on the bus to the built rekon-viewer; chromium loads the
// page afterwards (a late browser gets the whole map), then 50 blocks are
// corrected while a second browser watches. Exact counts: the page draws
// every block the viewer holds (400 blocks, 26 vertices and 24 triangles each).
TEST(ViewerBrowser, PageCountsAndDrawsEveryBlockOnTheBus) {
  if (!haveChromium()) GTEST_SKIP() << "chromium is not installed (tools/rekon deps installs it): skipping the browser test";
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  const pid_t viewer = rekon::test::spawnShell("exec " + binDir() + "/rekon-viewer --set viewer.port=0 --out " + dir.path() +
                                               " > " + (dir / "viewer.log") + " 2>&1");
  const std::string url = waitForUrl(dir / "viewer.log", 10.0);
  ASSERT_FALSE(url.empty()) << readText(dir / "viewer.log");
  auto bus = makeBus(BusOptions{});
  publish(*bus, wall(1), 1);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));

  const auto t0 = Clock::now();
  std::string dom;
  ASSERT_EQ(runCommand(chromium(dir / "profile1") + "--virtual-time-budget=5000 --dump-dom " + url + " 2>/dev/null", &dom), 0) << dom;
  const double dom_s = test::secondsSince(t0);
  EXPECT_EQ(dataCounter(dom, "blocks"), 400) << dom.substr(0, 600);
  EXPECT_EQ(dataCounter(dom, "vertices"), 400 * 26);
  EXPECT_EQ(dataCounter(dom, "triangles"), 400 * 24);

  const std::string shot = binDir() + "/../test_viewer_wall.png";
  std::string out;
  EXPECT_EQ(runCommand(chromium(dir / "profile2") + "--virtual-time-budget=5000 --screenshot=" + shot + " " + url, &out), 0) << out;
  const int drawn = drawnPixels(shot);
  // The wall fills the fitted view: about a third of the 1280x800 frame outside the panel.
  EXPECT_GT(drawn, 100000) << shot;
  std::cout << "dump-dom " << dom_s << " s; drawn pixels " << drawn << " of " << 1280 * 800 << " (" << shot << ")\n";

  EXPECT_EQ(rekon::test::waitForExit(viewer, 0.1), -1);  // still serving: stopped here by SIGTERM
  EXPECT_NE(readText(dir / "viewer_stats.json").find("\"blocks\": 400"), std::string::npos) << readText(dir / "viewer_stats.json");
}

}  // namespace
}  // namespace rekon::viewer
