// `rekon frontend-check` against rekon's own frontends, end to end on the bus
// (every process under a timeout in a private network namespace): the tracker
// and optimiser of `rekon run`, and rekon-replay beside player and mapper. It
// listens live, and judges the lcm-logger log of the same run the same way.
#include <gtest/gtest.h>

#include <string>

#include "test_support.hpp"

namespace {

using rekon::test::readText;
using rekon::test::runCommand;

std::string bin() { return rekon::test::binDir(); }

int passLines(const std::string& text) {
  int n = 0;
  for (size_t p = text.find("PASS FC"); p != std::string::npos; p = text.find("PASS FC", p + 1)) ++n;
  return n;
}

// The checker's verdict: every one of the 11 rules on its own PASS line, no FAIL.
void expectAllPass(const std::string& lines, const std::string& what) {
  EXPECT_EQ(passLines(lines), 11) << what << ":\n" << lines;
  EXPECT_EQ(lines.find("FAIL FC"), std::string::npos) << what << ":\n" << lines;
}

// The checker listening (it says so before the frontend starts), lcm-logger
// recording, then `frontend`; the checker's exit status and lines in DIR/check.log
// (a frontend that failed stops the checker at once).
std::string withChecker(const rekon::test::TempDir& dir, const std::string& check_args, const std::string& frontend) {
  return "timeout 200 " + bin() + "/rekon frontend-check --timeout 150 " + check_args + " > " + (dir / "check.log") +
         " 2>&1 & c=$!; lcm-logger -q \"--lcm-url=udpm://239.255.76.67:7667?ttl=0\" " + (dir / "run.lcm") +
         " & g=$!; for i in $(seq 100); do grep -q listening " + (dir / "check.log") + " && break; sleep 0.1; done; " +
         frontend + "; f=$?; [ $f = 0 ] || kill $c; wait $c; cc=$?; kill $g; wait $g; echo frontend=$f check=$cc; [ $f$cc = 00 ]";
}

}  // namespace

TEST(FrontendConformance, RekonTrackerAndOptimiserPass) {
  rekon::test::TempDir dir;
  std::string out;
  ASSERT_EQ(runCommand("timeout 120 " + bin() + "/rekon synth --scene room --frames 90 --out " + (dir / "room"), &out), 0)
      << out;
  const std::string run = "timeout 240 " + bin() + "/rekon run --dataset " + (dir / "room") + " --out " + (dir / "run") +
                          " > " + (dir / "run.log") + " 2>&1";
  const int rc = runCommand(rekon::test::inNetns() + " bash -c '" + withChecker(dir, "", run) + "'", &out);
  const std::string lines = readText(dir / "check.log");
  ASSERT_EQ(rc, 0) << out << "\ncheck:\n" << lines << "\nrun:\n" << readText(dir / "run.log");
  expectAllPass(lines, "live");
  std::string logged;
  EXPECT_EQ(runCommand(bin() + "/rekon frontend-check --log " + (dir / "run.lcm"), &logged), 0) << logged;
  expectAllPass(logged, "from the lcm-logger log");
}

TEST(FrontendConformance, RekonReplayPasses) {
  rekon::test::TempDir dir;
  std::string out;
  ASSERT_EQ(runCommand("timeout 120 " + bin() + "/rekon synth --scene tabletop --frames 40 --drift 0.05,3 --out " +
                           (dir / "data"),
                       &out),
            0)
      << out;
  const std::string segments = rekon::test::ownSegments("fcr");
  const std::string frontend =
      "timeout 120 " + bin() + "/rekon-mapper --out " + (dir / "out") + " --set mapper.kappa=5" + segments + " > " +
      (dir / "mapper.log") +
      " 2>&1 & m=$!; timeout 120 " + bin() + "/rekon-replay --trajectory " + (dir / "data/drifted_trajectory.txt") +
      " --target " + (dir / "data/groundtruth.txt") + " > " + (dir / "replay.log") + " 2>&1 & r=$!; timeout 120 " +
      bin() + "/rekon-player --dataset " + (dir / "data") + " --set player.wait_for=[replay,mapper]" + segments + " > " +
      (dir / "player.log") + " 2>&1; p=$?; wait $r; rr=$?; wait $m; mm=$?; [ $p$rr$mm = 000 ]";
  const int rc =
      runCommand(rekon::test::inNetns() + " bash -c '" + withChecker(dir, "--ack-name replay", frontend) + "'", &out);
  const std::string lines = readText(dir / "check.log");
  ASSERT_EQ(rc, 0) << out << "\ncheck:\n" << lines << "\nreplay:\n" << readText(dir / "replay.log") << "\nmapper:\n"
                   << readText(dir / "mapper.log");
  expectAllPass(lines, "live");
  std::string logged;
  EXPECT_EQ(runCommand(bin() + "/rekon frontend-check --ack-name replay --log " + (dir / "run.lcm"), &logged), 0)
      << logged;
  expectAllPass(logged, "from the lcm-logger log");
}

TEST(FrontendConformance, AFileThatIsNoRunLogIsOneLineAndAFailure) {
  rekon::test::TempDir dir;
  std::string out;
  ASSERT_EQ(runCommand("head -c 4096 /dev/urandom > " + (dir / "junk.lcm"), &out), 0) << out;
  EXPECT_EQ(runCommand(bin() + "/rekon frontend-check --log " + (dir / "junk.lcm"), &out), 1) << out;
  EXPECT_NE(out.find("junk.lcm: no message on a frontend channel"), std::string::npos) << out;
  EXPECT_EQ(runCommand(bin() + "/rekon frontend-check --log " + (dir / "absent.lcm"), &out), 1) << out;
  EXPECT_NE(out.find("absent.lcm: cannot open as an lcm-logger log"), std::string::npos) << out;
  EXPECT_EQ(rekon::test::crashLines(out), "") << out;
}
