// The page in a real browser: Debian's chromium, headless, opens rekon-viewer
// (the built binary, in this test's network namespace) while mesh blocks
// arrive on the bus, and the test reads what the page itself counted (its
// <body data-*> counters, through --dump-dom) and looks at its screenshot.
#include <gtest/gtest.h>

#include <signal.h>
#include <unistd.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <cmath>
#include <filesystem>
#include <regex>
#include <thread>

#include "rekon/common/bus.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/service_stats_t.hpp"
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
std::string chromium(const std::string& profile, int wall_s = 60) {
  return "timeout " + std::to_string(wall_s) + " chromium --headless=new --no-sandbox --disable-dev-shm-usage --use-angle=swiftshader "
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

// rekon-viewer on a free port, logging to DIR/viewer.log; its URL ("" when it did not listen within 10 s).
std::string startViewer(const rekon::test::TempDir& dir, pid_t* pid, const std::string& args = "") {
  *pid = rekon::test::spawnShell("exec " + binDir() + "/rekon-viewer --set viewer.port=0 " + args + " > " + (dir / "viewer.log") +
                                 " 2>&1");
  return waitForUrl(dir / "viewer.log", 10.0);
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

// The wall with `corrected` blocks of its first row re-sent as corrections
// and the next `grown` re-sent with new data (version 2).
std::vector<BlockMesh> resent(int corrected, int grown) {
  std::vector<BlockMesh> blocks;
  for (int i = 0; i < corrected + grown; ++i) {
    blocks.push_back(test::syntheticBlock({i % 20 - 10, i / 20 - 10, 20}, 2, 24));
    blocks.back().cause = i < corrected ? BlockCause::kCorrection : BlockCause::kNewData;
  }
  return blocks;
}

// The wall published on the bus to the built rekon-viewer, then 50 of its
// blocks corrected and 30 re-sent with new data; chromium loads the page
// afterwards (a late browser gets the whole map). Exact counts: the page
// draws every block the viewer holds (400 blocks, 26 vertices and 24
// triangles each), and of the versions it holds, the 50 corrections, not the
// 30 blocks that only grew, count as corrections (issue 27: every re-sent
// block used to count).
TEST(ViewerBrowser, PageCountsAndDrawsEveryBlockOnTheBus) {
  if (!haveChromium()) GTEST_SKIP() << "chromium is not installed (tools/rekon deps installs it): skipping the browser test";
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  pid_t viewer = 0;
  const std::string url = startViewer(dir, &viewer, "--out " + dir.path());
  ASSERT_FALSE(url.empty()) << readText(dir / "viewer.log");
  auto bus = makeBus(BusOptions{});
  publish(*bus, wall(1), 1);
  publish(*bus, resent(50, 30), 2);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));

  const auto t0 = Clock::now();
  std::string dom;
  ASSERT_EQ(runCommand(chromium(dir / "profile1") + "--virtual-time-budget=5000 --dump-dom " + url + " 2>/dev/null", &dom), 0) << dom;
  const double dom_s = test::secondsSince(t0);
  EXPECT_EQ(dataCounter(dom, "blocks"), 400) << dom.substr(0, 600);
  EXPECT_EQ(dataCounter(dom, "vertices"), 400 * 26);
  EXPECT_EQ(dataCounter(dom, "triangles"), 400 * 24);
  EXPECT_EQ(dataCounter(dom, "corrections"), 50) << dom.substr(0, 600);
  EXPECT_EQ(dataCounter(dom, "final_pass"), 0);
  EXPECT_NE(dom.find("50 blocks corrected"), std::string::npos);

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

// A browser without WebGL (issue 27: the page sat on "connecting..." with an
// empty status table): the status, the counts and one line saying the 3D view
// needs WebGL.
TEST(ViewerBrowser, PageWithoutWebGLShowsTheStatusAndSaysWhatIsMissing) {
  if (!haveChromium()) GTEST_SKIP() << "chromium is not installed (tools/rekon deps installs it): skipping the browser test";
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  pid_t viewer = 0;
  const std::string url = startViewer(dir, &viewer);
  ASSERT_FALSE(url.empty()) << readText(dir / "viewer.log");
  auto bus = makeBus(BusOptions{});
  publish(*bus, wall(1), 1);
  rekon_msgs::heartbeat_t hb{};
  hb.schema_version = kSchemaVersion;
  hb.service = "mapper";
  hb.pid = 4242;
  hb.host = "test";
  hb.last_frame_id = 17;
  hb.state = "running";
  bus->publish(channel::kHeartbeat, hb);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));

  std::string dom;
  ASSERT_EQ(runCommand(chromium(dir / "profile") + "--disable-webgl --disable-3d-apis --virtual-time-budget=5000 --dump-dom " +
                           url + " 2>/dev/null", &dom), 0) << dom;
  EXPECT_NE(dom.find("data-webgl=\"0\""), std::string::npos) << dom.substr(0, 800);
  EXPECT_NE(dom.find("The 3D view needs WebGL"), std::string::npos) << dom.substr(0, 1500);
  // The 3D view's controls are hidden; the PLY download stays.
  EXPECT_TRUE(std::regex_search(dom, std::regex("<button id=\"fit\"[^>]*hidden"))) << dom.substr(0, 1500);
  EXPECT_TRUE(std::regex_search(dom, std::regex("<label class=\"needs3d\"[^>]*hidden[^>]*><input[^>]*id=\"follow\"")))
      << dom.substr(0, 1500);
  EXPECT_TRUE(std::regex_search(dom, std::regex("<a id=\"download\" href=\"/mesh.ply\" download=\"mesh.ply\">")));
  EXPECT_NE(dom.find(">live<"), std::string::npos);  // connected, not "connecting..."
  EXPECT_TRUE(std::regex_search(dom, std::regex("<td>mapper</td><td>[a-z]+</td><td>17</td>"))) << dom;
  EXPECT_EQ(dataCounter(dom, "blocks"), 400);
  EXPECT_NE(dom.find("data-run-finished=\"0\""), std::string::npos) << dom.substr(0, 800);

  // The mapper killed and restarted, and a camera back from an outage (issue
  // 48): the status says both.
  hb.pid = 4343;
  hb.last_frame_id = 18;
  bus->publish(channel::kHeartbeat, hb);
  rekon_msgs::heartbeat_t camera = hb;
  camera.service = "camera";
  camera.pid = 4444;
  bus->publish(channel::kHeartbeat, camera);
  rekon_msgs::service_stats_t camera_stats{};
  camera_stats.schema_version = kSchemaVersion;
  camera_stats.service = "camera";
  camera_stats.json = R"({"outages": 1, "frames_missed_in_outages": 31})";
  bus->publish(channel::kStats, camera_stats);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  ASSERT_EQ(runCommand(chromium(dir / "profile_restart") + "--disable-webgl --disable-3d-apis --virtual-time-budget=5000 "
                           "--dump-dom " + url + " 2>/dev/null", &dom), 0) << dom;
  EXPECT_TRUE(std::regex_search(dom, std::regex("<td>mapper</td><td>[a-z]+ \\(1 restart\\)</td><td>18</td>"))) << dom;
  EXPECT_NE(dom.find("outages 1, frames missed in outages 31"), std::string::npos) << dom;

  // Every service exited (here the one there was): the header says the run
  // is over (it said "live"), and an exited service shows no frame rate.
  hb.state = camera.state = "exited";
  bus->publish(channel::kHeartbeat, hb);
  bus->publish(channel::kHeartbeat, camera);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  ASSERT_EQ(runCommand(chromium(dir / "profile_end") + "--disable-webgl --disable-3d-apis --virtual-time-budget=5000 --dump-dom " +
                           url + " 2>/dev/null", &dom), 0) << dom;
  EXPECT_NE(dom.find("data-run-finished=\"1\""), std::string::npos) << dom.substr(0, 800);
  EXPECT_NE(dom.find(">run finished: its final map<"), std::string::npos) << dom.substr(0, 1500);
  EXPECT_TRUE(std::regex_search(dom, std::regex("<td>mapper</td><td>exited \\(1 restart\\)</td><td>18</td><td></td>"))) << dom;
  const std::string shot = binDir() + "/../test_viewer_no_webgl.png";
  runCommand(chromium(dir / "profile2") + "--disable-webgl --disable-3d-apis --virtual-time-budget=5000 --screenshot=" + shot +
             " " + url + " 2>&1");
  EXPECT_EQ(rekon::test::waitForExit(viewer, 0.1), -1);
}

std::string stateJson(const std::string& url) {
  std::string out;
  runCommand("curl -s --max-time 5 " + url + "state.json", &out);
  return out;
}

using rekon::test::jsonInt;
using rekon::test::jsonNumber;

// The first page's report in /state.json ("" before one came).
std::string pageReport(const std::string& state) {
  const size_t at = state.find("\"clients\":[{");
  return at == std::string::npos ? "" : state.substr(at, state.find('}', at) - at + 1);
}

// /state.json every 250 ms until done(its first page's report, it) or
// `seconds` have passed; the last one read.
template <typename Done>
std::string waitForState(const std::string& url, Done done, double seconds) {
  std::string state;
  const auto start = Clock::now();
  do {
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
    state = stateJson(url);
  } while (!done(pageReport(state), state) && test::secondsSince(start) < seconds);
  return state;
}

// The report of a page opened now on `url` once it holds `blocks` blocks, or
// its last report after `seconds`; chromium runs in real time (its debugging
// port keeps the page open) and is stopped before this returns. Pages loaded
// with --virtual-time-budget instead could end their budget before the
// WebSocket had brought every block, however large the budget (CI, a loaded
// 2-core VM: 958 of 4 414 blocks after five loads of 60-960 virtual seconds).
std::string pageHolding(const std::string& url, const std::string& profile, long long blocks, int seconds) {
  const pid_t browser = rekon::test::spawnShell("exec " + chromium(profile, seconds + 30) + "--remote-debugging-port=0 " + url +
                                                " > " + profile + ".log 2>&1");
  const std::string page = pageReport(
      waitForState(url, [blocks](const std::string& p, const std::string&) { return jsonInt(p, "blocks") == blocks; }, seconds));
  kill(browser, SIGTERM);
  rekon::test::waitForExit(browser, 10);
  return page;
}

// Issue 27: the mapper sends a block no subscriber has seen first as a coarse
// mesh (an odd time version), its full mesh later (the next, even version).
// A page open the whole time draws the coarse wall at once, then replaces
// every block in place by its full mesh: it ends with the viewer's very
// versions (equal sums of every vertex coordinate), no coarse block left,
// and a completed coarse mesh counts as no update; its latency splits into
// first appearances and full meshes.
TEST(ViewerBrowser, AnOpenPageReplacesCoarseMeshesByTheFullOnes) {
  if (!haveChromium()) GTEST_SKIP() << "chromium is not installed (tools/rekon deps installs it): skipping the browser test";
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  pid_t viewer = 0;
  const std::string url = startViewer(dir, &viewer);
  ASSERT_FALSE(url.empty()) << readText(dir / "viewer.log");
  const pid_t browser = rekon::test::spawnShell("exec " + chromium(dir / "profile", 200) + "--remote-debugging-port=0 " +
                                                url + " > " + (dir / "chromium.log") + " 2>&1");
  // Reports come once a second; the page is live once one has come.
  auto waitForPage = [&](auto done) { return waitForState(url, done, 90); };
  ASSERT_FALSE(pageReport(waitForPage([](const std::string& page, const std::string&) { return !page.empty(); })).empty())
      << readText(dir / "chromium.log");
  auto bus = makeBus(BusOptions{});
  const int64_t now_us = std::chrono::duration_cast<std::chrono::microseconds>(
      std::chrono::system_clock::now().time_since_epoch()).count();
  const int64_t change = now_us + (now_us & 1);  // even: the full mesh's version
  std::vector<BlockMesh> coarse;
  for (const BlockMesh& b : wall(change - 1)) coarse.push_back(test::syntheticBlock({b.x, b.y, b.z}, change - 1, 6));
  publish(*bus, coarse, 1);
  std::string state = waitForPage([](const std::string& page, const std::string&) { return jsonInt(page, "blocks") == 400; });
  std::string page = pageReport(state);
  EXPECT_EQ(jsonInt(page, "coarse"), 400) << page;
  EXPECT_EQ(jsonInt(page, "triangles"), 400 * 6) << page;
  EXPECT_EQ(jsonInt(state, "coarse_blocks"), 400) << state.substr(0, 300);

  publish(*bus, wall(change), 2);
  state = waitForPage([](const std::string& p, const std::string& s) {
    return jsonInt(p, "coarse") == 0 && std::abs(jsonNumber(p, "position_sum") - jsonNumber(s, "position_sum")) < 1e-3;
  });
  page = pageReport(state);
  EXPECT_EQ(jsonInt(page, "coarse"), 0) << page;
  EXPECT_EQ(jsonInt(page, "blocks"), 400);
  EXPECT_EQ(jsonInt(page, "triangles"), 400 * 24);
  EXPECT_NEAR(jsonNumber(page, "position_sum"), jsonNumber(state, "position_sum"), 1e-3) << page;
  EXPECT_EQ(jsonInt(page, "updates"), 0) << page;  // completing a coarse mesh is no update
  EXPECT_EQ(jsonInt(state, "coarse_blocks"), 0);
  EXPECT_EQ(jsonInt(page, "latency_new_samples"), 400) << page;   // the coarse wall's first appearance
  EXPECT_EQ(jsonInt(page, "latency_full_samples"), 400) << page;  // and its full meshes
  EXPECT_EQ(jsonInt(page, "latency_samples"), 800) << page;
  kill(browser, SIGTERM);
  rekon::test::waitForExit(browser, 10);
  rekon::test::waitForExit(viewer, 0.1);
}

// The whole pipeline (rekon run --view) on 150 frames of the synthetic room,
// played at its recorded rate (5 s) so that a browser opens mid-run,
// with a second, standalone rekon-viewer listening from the start: a browser
// mid-run draws the growing map, and one that loads after the run counts
// what the mapper's mesh.ply holds. Measured on 60 frames (2-core machine):
// 2341 blocks, 286984 triangles in the page and in mesh.ply alike; 185501
// vertices in the page against 147344 in mesh.ply (the page keeps each
// block's own copy of the vertices on faces it shares with a neighbour: +26 %).
TEST(ViewerBrowser, PageReachesTheMeshOfASyntheticRun) {
  if (!haveChromium()) GTEST_SKIP() << "chromium is not installed (tools/rekon deps installs it): skipping the browser test";
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene room --frames 150 --out " + (dir / "room")), 0);
  pid_t viewer = 0;
  const std::string url = startViewer(dir, &viewer);
  ASSERT_FALSE(url.empty()) << readText(dir / "viewer.log");
  const pid_t run = rekon::test::spawnShell("exec timeout 240 " + binDir() + "/rekon run --view --set viewer.port=0 "
                                            "--set viewer.serve_after_run_s=0 --set player.rate=1 --dataset " +
                                            (dir / "room") + " --out " + (dir / "run") + " > " + (dir / "run.log") + " 2>&1");
  // Mid-run: once the map has blocks, a browser draws them.
  const auto start = Clock::now();
  while (jsonInt(stateJson(url), "blocks") <= 0 && test::secondsSince(start) < 120) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  const std::string live_shot = binDir() + "/../test_viewer_room_live.png";
  runCommand(chromium(dir / "profile1") + "--virtual-time-budget=5000 --screenshot=" + live_shot + " " + url + " 2>&1");
  const int live_drawn = drawnPixels(live_shot);
  // The first blocks, a few thousand pixels at least (56227 and 111094 measured: the mapper's final pass
  // arriving, its re-meshed blocks highlighted).
  EXPECT_GT(live_drawn, 2000) << live_shot;

  EXPECT_EQ(rekon::test::waitForExit(run, 240), 0) << readText(dir / "run.log");
  const std::string run_log = readText(dir / "run.log");
  EXPECT_TRUE(std::regex_search(run_log, std::regex(R"(viewer: http://127\.0\.0\.1:[0-9]+/)"))) << run_log;  // --view's URL
  std::this_thread::sleep_for(std::chrono::seconds(1));  // the mapper's last blocks reach the viewer
  const Mesh ply = readPly(dir / "run/mesh.ply");
  const std::string state = stateJson(url);

  // A page opened after the run takes the whole map: what it counts is what it drew.
  const std::string page = pageHolding(url, dir / "profile2", jsonInt(state, "blocks"), 180);
  const long long blocks = jsonInt(page, "blocks"), vertices = jsonInt(page, "vertices"),
                  triangles = jsonInt(page, "triangles"), corrections = jsonInt(page, "corrections"),
                  final_pass = jsonInt(page, "final_pass");
  EXPECT_EQ(blocks, jsonInt(state, "blocks")) << state.substr(0, 200) << "\n" << page;
  EXPECT_GT(blocks, 0);
  // Triangles: 1 % for messages LCM may lose on a loaded machine (none were lost in the measured runs).
  EXPECT_NEAR(static_cast<double>(triangles), static_cast<double>(ply.triangles.size()), 0.01 * static_cast<double>(ply.triangles.size()));
  EXPECT_GE(vertices, static_cast<long long>(ply.vertices.size()));
  EXPECT_LE(vertices, static_cast<long long>(1.4 * static_cast<double>(ply.vertices.size())));  // +26 % measured
  // Issue 27: this run re-integrates nothing (0 graph-update re-integrations
  // measured: no loop closes in 150 frames), so no block is a correction; a
  // block the final pass re-meshed counts only when the final pass moved one.
  const std::string mapper_stats = readText(dir / "run/mapper_stats.json");
  ASSERT_EQ(jsonInt(mapper_stats, "reintegrations"), 0) << mapper_stats;
  EXPECT_EQ(corrections, 0);
  EXPECT_EQ(final_pass > 0, jsonInt(mapper_stats, "final_pass_reintegrations") > 0) << final_pass << "\n" << mapper_stats;

  // The whole map drawn by swiftshader takes real time on a loaded 2-core
  // machine: once a 60 s wall limit cut chromium off before its screenshot
  // (none written). 180 s, and a second try when none came.
  const std::string shot = binDir() + "/../test_viewer_room.png";
  std::string chromium_out;
  std::filesystem::remove(shot);  // never a screenshot of an earlier run
  for (int attempt = 0; attempt < 2 && !std::filesystem::exists(shot); ++attempt) {
    runCommand(chromium(dir / ("profile3_" + std::to_string(attempt)), 180) + "--virtual-time-budget=30000 --screenshot=" +
                   shot + " " + url + " 2>&1",
               &chromium_out);
  }
  const int drawn = drawnPixels(shot);
  EXPECT_GE(drawn, 0) << "no screenshot; chromium said:\n" << chromium_out;
  EXPECT_GT(drawn, 50000) << shot;  // the room in the fitted view: 76442 and 80563 pixels measured
  std::cout << "page: " << blocks << " blocks " << vertices << " vertices " << triangles << " triangles; mesh.ply "
            << ply.vertices.size() << " vertices " << ply.triangles.size() << " triangles; drawn pixels live " << live_drawn
            << " final " << drawn << "\n";
  rekon::test::waitForExit(viewer, 0.1);
}


// rekon run --view (issue 27: the viewer was stopped about 1 s after the final
// map reached it, and the URL refused afterwards): once the run has finished,
// the viewer says so with its URL and keeps the final map, which a page
// opened now draws whole and /mesh.ply serves, until Ctrl-C, which then ends
// the finished run with exit 0.
TEST(ViewerBrowser, RunViewKeepsServingTheFinalMapUntilCtrlC) {
  if (!haveChromium()) GTEST_SKIP() << "chromium is not installed (tools/rekon deps installs it): skipping the browser test";
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene room --frames 30 --out " + (dir / "room") +
                       " > /dev/null 2>&1"), 0);
  const pid_t run = rekon::test::spawnShell("exec timeout 400 " + binDir() + "/rekon run --view --set viewer.port=0 --dataset " +
                                            (dir / "room") + " --out " + (dir / "run") + " > " + (dir / "run.log") + " 2>&1");
  const std::regex finished(R"(the run has finished; the viewer shows its final map at (http://127\.0\.0\.1:[0-9]+/) until Ctrl-C)");
  std::smatch m;
  const auto start = Clock::now();
  std::string log;
  while (!std::regex_search(log = readText(dir / "run.log"), m, finished) && test::secondsSince(start) < 120) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  ASSERT_FALSE(m.empty()) << log;
  const std::string url = m[1];
  std::this_thread::sleep_for(std::chrono::seconds(3));  // still serving well after the run
  const std::string state = stateJson(url);
  const Mesh ply = readPly(dir / "run/mesh.ply");
  // The viewer holds the final map: mesh.ply's triangles (1 % for LCM messages a loaded machine may lose).
  EXPECT_NEAR(static_cast<double>(jsonInt(state, "triangles")), static_cast<double>(ply.triangles.size()),
              0.01 * static_cast<double>(ply.triangles.size())) << state.substr(0, 300);
  EXPECT_EQ(jsonInt(pageHolding(url, dir / "profile", jsonInt(state, "blocks"), 180), "blocks"), jsonInt(state, "blocks"));
  std::string head;
  runCommand("curl -s --max-time 30 -o /dev/null -w '%{http_code}' " + url + "mesh.ply", &head);
  EXPECT_EQ(head, "200");
  kill(run, SIGINT);
  EXPECT_EQ(rekon::test::waitForExit(run, 30), 0) << readText(dir / "run.log");
  EXPECT_NE(runCommand("curl -s --max-time 5 " + url + "state.json > /dev/null"), 0);  // stopped now
  std::cout << "served after the run: " << jsonInt(state, "blocks") << " blocks, " << jsonInt(state, "triangles")
            << " triangles; mesh.ply " << ply.triangles.size() << " triangles\n";
}

// A correction the page must show. rekon-replay stands in for the tracker and
// the optimiser: it replays a drifted trajectory and, after the stream, moves
// every keyframe onto the ground truth in 4 graph updates 0.5 s apart; the
// mapper de- and re-integrates and sends the re-meshed blocks. A browser kept
// open the whole time (chromium holds a page while its debugging port is
// open) reports what it holds: it must end with the viewer's blocks, the very
// same versions (equal sums of every vertex coordinate), after replacing
// blocks in place; and the viewer's mesh is the corrected mesh.ply, far from
// mesh_uncorrected.ply. The page also measured its update latency, and the
// mapper's live numbers (STATS) reached the status panel.
TEST(ViewerBrowser, PageShowsTheCorrectionOfAGraphUpdate) {
  if (!haveChromium()) GTEST_SKIP() << "chromium is not installed (tools/rekon deps installs it): skipping the browser test";
  if (!rekon::test::insideNetns()) return;
  rekon::test::TempDir dir;
  ASSERT_EQ(runCommand("timeout 120 " + binDir() + "/rekon synth --scene room --frames 60 --drift 0.05,3 --out " +
                       (dir / "data")), 0);
  pid_t viewer = 0;
  const std::string url = startViewer(dir, &viewer, "--out " + (dir / "viewer"));
  ASSERT_FALSE(url.empty()) << readText(dir / "viewer.log");
  const pid_t browser = rekon::test::spawnShell("exec " + chromium(dir / "profile", 400) + "--remote-debugging-port=0 " +
                                                url + " > " + (dir / "chromium.log") + " 2>&1");
  const auto reported = [](const std::string& page, const std::string&) { return !page.empty(); };
  ASSERT_FALSE(pageReport(waitForState(url, reported, 90)).empty()) << "the page never reported:\n"
                                                                        << readText(dir / "chromium.log");

  const std::string bin = binDir(), id = std::to_string(getpid());
  const std::string pipeline =
      bin + "/rekon-mapper --out " + (dir / "out") + " --set mapper.kappa=5 --set mapper.m=2 --set mapper.store_segment=rekon_vbt_kf_" +
      id + " > " + (dir / "mapper.log") + " 2>&1 & m=$!; " + bin + "/rekon-replay --trajectory " +
      (dir / "data/drifted_trajectory.txt") + " --target " + (dir / "data/groundtruth.txt") +
      " --update-every 0 --gap-ms 500 > " + (dir / "replay.log") + " 2>&1 & r=$!; " + bin + "/rekon-player --dataset " +
      (dir / "data") + " --set player.wait_for=[replay,mapper] --set player.wait_timeout_s=60 --set transport.segment=rekon_vbt_" +
      id + " > " + (dir / "player.log") + " 2>&1; p=$?; wait $r; rr=$?; wait $m; mm=$?; [ $p$rr$mm = 000 ]";
  ASSERT_EQ(runCommand("timeout 240 bash -c '" + pipeline + "'"), 0)
      << readText(dir / "mapper.log") << readText(dir / "replay.log") << readText(dir / "player.log");

  // The page takes the last blocks and reports within a few seconds.
  const std::string state = waitForState(
      url,
      [](const std::string& p, const std::string& st) {
        return jsonInt(p, "blocks") == jsonInt(st, "blocks") &&
               !(std::abs(jsonNumber(p, "position_sum") - jsonNumber(st, "position_sum")) > 1e-3);
      },
      60);
  const std::string page = pageReport(state);
  const std::string mapper_stats = readText(dir / "out/mapper_stats.json");
  EXPECT_GT(rekon::test::jsonInt(mapper_stats, "final_pass_reintegrations"), 0) << mapper_stats;
  EXPECT_EQ(jsonInt(page, "blocks"), jsonInt(state, "blocks")) << page << "\n" << state.substr(0, 400);
  EXPECT_EQ(jsonInt(page, "vertices"), jsonInt(state, "vertices"));
  EXPECT_EQ(jsonInt(page, "triangles"), jsonInt(state, "triangles"));
  // float32 coordinates added up in double on both sides, in another order: ~1e-6 of the sum's size.
  EXPECT_NEAR(jsonNumber(page, "position_sum"), jsonNumber(state, "position_sum"), 1e-3) << page;
  EXPECT_GT(jsonInt(page, "updates"), 0) << page;           // blocks replaced in place while it watched
  // The graph updates re-integrated and the final pass re-meshed: both are
  // highlighted as corrections; what the page saw of them is what the viewer
  // took (the page was open from the start; coalescing can only lower it).
  EXPECT_GT(jsonInt(page, "corrections") + jsonInt(page, "final_pass"), 0) << page;
  EXPECT_LE(jsonInt(page, "corrections"), jsonInt(state, "block_corrections")) << state.substr(0, 400);
  EXPECT_LE(jsonInt(page, "final_pass"), jsonInt(state, "final_pass_blocks"));
  EXPECT_GT(jsonInt(page, "latency_samples"), 0) << page;   // and timed from the mapper's change
  EXPECT_EQ(jsonInt(page, "coarse"), 0) << page;  // every coarse mesh (issue 27) replaced by its full one
  EXPECT_NE(state.find("reintegrations"), std::string::npos) << state.substr(0, 2000);  // the mapper's STATS

  ASSERT_EQ(runCommand("curl -s --max-time 30 -o " + (dir / "page.ply") + " " + url + "mesh.ply"), 0);
  std::string eval_out;
  runCommand(bin + "/rekon eval surface " + (dir / "page.ply") + " " + (dir / "out/mesh.ply"), &eval_out);
  const double to_corrected = rekon::test::valueAfter(eval_out, "corr_m");
  runCommand(bin + "/rekon eval surface " + (dir / "page.ply") + " " + (dir / "out/mesh_uncorrected.ply"), &eval_out);
  const double to_uncorrected = rekon::test::valueAfter(eval_out, "corr_m");
  EXPECT_GE(to_corrected, 0.0);
  EXPECT_LT(to_corrected, 5e-4);  // 89 um measured (10 um quantisation; the page's blocks keep their own vertex copies)
  EXPECT_GT(to_uncorrected, 10 * to_corrected + 1e-3);  // 9.6 mm measured: the drift the correction removed
  std::cout << "page " << page << "\nCORR page mesh to mesh.ply " << to_corrected << " m, to mesh_uncorrected.ply "
            << to_uncorrected << " m\n";
  kill(browser, SIGTERM);
  rekon::test::waitForExit(browser, 10);
  rekon::test::waitForExit(viewer, 0.1);
}

}  // namespace
}  // namespace rekon::viewer
