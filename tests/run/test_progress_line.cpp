// The progress line of rekon run, demo and synth (issue 27: nothing printed
// during a 30-60 s run): rewritten in place on a terminal, with log lines
// clearing it first; plain lines elsewhere.
#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <cstdio>
#include <string>
#include <thread>

#include "rekon/progress/progress_line.hpp"

namespace {

std::string contentsOf(std::FILE* f) {
  std::fflush(f);
  std::rewind(f);
  std::string s;
  for (int c; (c = std::fgetc(f)) != EOF;) s.push_back(static_cast<char>(c));
  return s;
}

TEST(ProgressLine, OnATerminalOneLineIsRewrittenAndALogLineClearsItFirst) {
  std::FILE* f = std::tmpfile();
  {
    rekon::ProgressLine line(f, true);
    line.update("frame 1/10");
    line.update("frame 2/10");  // within kTtyEveryS of the first: not shown
    std::this_thread::sleep_for(std::chrono::duration<double>(rekon::ProgressLine::kTtyEveryS + 0.05));
    line.update("frame 5/10");
    spdlog::info("a log line");  // the default logger writes to stdout: only the clearing lands in f
    line.finish("frame 10/10");
  }
  EXPECT_EQ(contentsOf(f), "\r\033[Kframe 1/10\r\033[Kframe 5/10\r\033[K\r\033[Kframe 10/10\n");
  std::fclose(f);
}

TEST(ProgressLine, ElsewhereItIsAPlainLineEveryFewSeconds) {
  std::FILE* f = std::tmpfile();
  {
    rekon::ProgressLine line(f, false);
    line.update("frame 1/10");
    line.update("frame 2/10");  // within kPlainEveryS: not shown
    line.finish("frame 10/10");
  }
  EXPECT_EQ(contentsOf(f), "frame 1/10\nframe 10/10\n");
  std::fclose(f);
}

TEST(ProgressLine, FrameProgressSaysDoneTotalRateRealtimeAndEta) {
  EXPECT_EQ(rekon::frameProgress(150, 600, 25.0, 0.83), "frame 150/600 (25 %), 25.0 fps, 0.83x realtime, ETA 18 s");
  EXPECT_EQ(rekon::frameProgress(600, 600, 25.0, 0.83), "frame 600/600 (100 %), 25.0 fps, 0.83x realtime");
  EXPECT_EQ(rekon::frameProgress(42, 0, 30.0), "frame 42, 30.0 fps");  // a live camera: no end, no realtime factor
  EXPECT_EQ(rekon::frameProgress(0, 600, 0.0, 0.0), "frame 0/600 (0 %)");
}

TEST(ProgressLine, TheLastLineOfAStoppedRunHasNoEta) {
  // Ctrl-C at frame 150 of 600: what was done, at what rate, and no time left to wait for.
  EXPECT_EQ(rekon::frameProgress(150, 600, 25.0, 0.83, true), "frame 150/600 (25 %), 25.0 fps, 0.83x realtime");
}

}  // namespace
