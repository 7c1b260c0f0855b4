// `rekon run` on broken datasets: the player stops at the broken input, the
// launcher stops the other services and ends with one line naming the player
// and its log, which holds the line naming the file. No service crashes on the
// way down.
#include "broken_dataset.hpp"

namespace rekon::hostile {
namespace {

Outcome rekonRun(const std::string& dataset, const std::string& out) {
  Outcome o;
  o.status = test::runCommand(test::sourceDir() + "/tests/support/in_netns.sh timeout -k 5 120 " + test::binDir() +
                                  "/rekon run --dataset " + dataset + " --out " + out,
                              &o.output);
  return o;
}

using rekon::test::readText;

TEST(BrokenRun, ATruncatedFrameEndsWithOneLinePointingAtThePlayerLog) {
  test::TempDir dir;
  makeDataset(dir / "d");
  truncate(dir / "d/depth/2.png");
  const Outcome o = rekonRun(dir / "d", dir / "out");
  EXPECT_EQ(o.status, 1) << o.output;
  // The launcher logs the failure when it happens and again as its last line.
  const auto lines = errorLines(o.output);
  ASSERT_FALSE(lines.empty()) << o.output;
  for (const auto& line : lines) {
    EXPECT_NE(line.find("rekon-player exited with status 1"), std::string::npos) << line;
    EXPECT_NE(line.find(dir / "out/player.log"), std::string::npos) << line;
  }
  const auto player_errors = errorLines(readText(dir / "out/player.log"));
  ASSERT_EQ(player_errors.size(), 1u) << readText(dir / "out/player.log");
  EXPECT_NE(player_errors[0].find("depth/2.png"), std::string::npos) << player_errors[0];
  for (const char* s : {"player", "tracker", "optimiser", "mapper"}) {
    EXPECT_EQ(test::crashLines(readText(dir / (std::string("out/") + s + ".log"))), "") << s << ".log";
  }
}

// Issue 27: found before any service starts (it used to be the player's
// error after every service had started, leaving an empty run in --out).
TEST(BrokenRun, AnEmptyFolderIsRefusedUpFrontNamingTheMissingCameraFile) {
  test::TempDir dir;
  fs::create_directories(dir / "empty");
  const Outcome o = rekonRun(dir / "empty", dir / "out");
  EXPECT_EQ(o.status, 1) << o.output;
  EXPECT_EQ(test::crashLines(o.output), "");
  EXPECT_EQ(o.output.find("started rekon-"), std::string::npos) << o.output;
  EXPECT_NE(o.output.find("camera.yaml"), std::string::npos) << o.output;
  EXPECT_FALSE(fs::exists(dir / "out"));
}

}  // namespace
}  // namespace rekon::hostile
