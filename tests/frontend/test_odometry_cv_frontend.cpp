// rekon-odometry_cv, OpenCV's RGB-D odometry as a second frontend, end to end
// (`rekon run` with it in place of tracker and optimiser, in a private
// network namespace): it passes `rekon frontend-check`, and the mapper builds
// the room from its poses.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "test_support.hpp"

namespace {

using rekon::test::readText;
using rekon::test::runCommand;

std::string bin() { return rekon::test::binDir(); }

}  // namespace

TEST(OdometryCvFrontend, DrivesTheMapperAndPassesFrontendCheck) {
  rekon::test::TempDir dir;
  std::string out;
  ASSERT_EQ(runCommand("timeout 120 " + bin() + "/rekon synth --scene room --frames 90 --out " + (dir / "room"), &out), 0)
      << out;
  const std::string run = "timeout 240 " + bin() + "/rekon run --dataset " + (dir / "room") + " --out " + (dir / "run") +
                          " --set run.services=[player,odometry_cv,mapper] --set player.wait_for=[odometry_cv,mapper]" +
                          " > " + (dir / "run.log") + " 2>&1";
  // The player at rate max keeps transport.slots - 1 frames in flight, so a
  // frame waits for those before it: latency = in-flight x ms per frame
  // (measured median 1.4 s, p95 1.9 s, max 2.0 s at 68 ms per frame on this
  // loaded 2-core machine; rekon's tracker: 6 ms median). Bound 4 s, twice the max.
  const std::string script = "timeout 260 " + bin() + "/rekon frontend-check --timeout 240 --ack-name odometry_cv --max-latency-ms 4000 > " +
                             (dir / "check.log") + " 2>&1 & c=$!; for i in $(seq 100); do grep -q listening " +
                             (dir / "check.log") + " && break; sleep 0.1; done; " + run +
                             "; f=$?; [ $f = 0 ] || kill $c; wait $c; cc=$?; echo run=$f check=$cc; [ $f$cc = 00 ]";
  const int rc = runCommand(rekon::test::inNetns() + " bash -c '" + script + "'", &out);
  const std::string lines = readText(dir / "check.log");
  ASSERT_EQ(rc, 0) << out << "\ncheck:\n" << lines << "\nrun:\n" << readText(dir / "run.log") << "\nodometry_cv:\n"
                   << readText(dir / "run/odometry_cv.log");
  EXPECT_EQ(lines.find("FAIL FC"), std::string::npos) << lines;
  EXPECT_NE(lines.find("PASS FC11"), std::string::npos) << lines;
  const double ate = rekon::test::ateOf(dir / "room/groundtruth.txt", dir / "run/trajectory.txt");
  std::printf("odometry_cv on the synthetic room (90 frames): ATE %.2f mm\n", 1e3 * ate);
  EXPECT_GT(ate, 0.0);
  // Measured 44.73 mm in 2 runs (the same frames, the same poses: the odometry
  // is deterministic); 10 % over. rekon's DVO tracker does better on this
  // synthetic room; on the real sequences see services/odometry_cv/README.md.
  EXPECT_LT(ate, 0.049);
  const std::string stats = readText(dir / "run/mapper_stats.json");
  EXPECT_EQ(rekon::test::jsonInt(stats, "frames_fused"), 90) << stats;
}
