// The optimiser's journal (services/optimiser/node/journal.hpp): what is
// appended comes back exactly and in order, a first instance starts it
// empty, and a line torn by a kill ends what is read and is cut off before
// the restart appends.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <string>
#include <variant>

#include "journal.hpp"
#include "test_support.hpp"

namespace rekon::optimiser {
namespace {

Pose turned(double x, double angle) {
  Pose p = Pose::Identity();
  p.linear() = Eigen::AngleAxisd(angle, Eigen::Vector3d(0.3, -1.0, 0.2).normalized()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(x, std::sqrt(2.0), -1.0 / 3.0);
  return p;
}

std::vector<GraphItem> twoKeyframesAndAnEdge() {
  Constraint c;
  c.kind = EdgeKind::Loop;
  c.from_id = 0;
  c.to_id = 1;
  c.relative = turned(0.1, 0.01);
  for (int i = 0; i < 36; ++i) c.information(i / 6, i % 6) = i / 6 == i % 6 ? 1e4 / 3.0 : 0.1 * (i % 7);
  return {KeyframeIn{0, turned(0.0, 0.0)}, KeyframeIn{1, turned(0.1, 0.01)}, c};
}

std::vector<TrackedFrame> frames(int64_t first, int64_t count) {
  std::vector<TrackedFrame> out;
  for (int64_t id = first; id < first + count; ++id)
    out.push_back(TrackedFrame{id, id / 30.0, id / 20, turned(0.001 * static_cast<double>(id), 0.002), id % 7 == 3});
  return out;
}

size_t linesIn(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  size_t n = 0;
  while (std::getline(in, line)) ++n;
  return n;
}

TEST(Journal, WhatIsAppendedComesBackExactlyInOrder) {
  test::TempDir dir;
  const auto items = twoKeyframesAndAnEdge();
  const auto written = frames(0, 40);
  Journal(dir.path(), false).append(items, written);
  const Journal again(dir.path(), true);
  const JournalContents& read = again.contents();
  EXPECT_EQ(read.lines_read, 43u);
  ASSERT_EQ(read.items.size(), 3u);
  EXPECT_EQ(std::get<KeyframeIn>(read.items[1]).id, 1);
  EXPECT_EQ(std::get<KeyframeIn>(read.items[1]).pose_world.matrix(), std::get<KeyframeIn>(items[1]).pose_world.matrix());
  const auto& c = std::get<Constraint>(read.items[2]);
  const auto& want = std::get<Constraint>(items[2]);
  EXPECT_EQ(c.kind, EdgeKind::Loop);
  EXPECT_EQ(c.relative.matrix(), want.relative.matrix());
  EXPECT_EQ(c.information, want.information);
  ASSERT_EQ(read.frames.size(), written.size());
  for (size_t i = 0; i < written.size(); ++i) {
    EXPECT_EQ(read.frames[i].frame_id, written[i].frame_id);
    EXPECT_EQ(read.frames[i].timestamp, written[i].timestamp);
    EXPECT_EQ(read.frames[i].keyframe_id, written[i].keyframe_id);
    EXPECT_EQ(read.frames[i].lost, written[i].lost);
    EXPECT_EQ(read.frames[i].pose_in_keyframe.matrix(), written[i].pose_in_keyframe.matrix());
  }
}

TEST(Journal, AFirstInstanceStartsItEmpty) {
  test::TempDir dir;
  Journal(dir.path(), false).append(twoKeyframesAndAnEdge(), frames(0, 10));
  const Journal fresh(dir.path(), false);
  EXPECT_EQ(fresh.contents().lines_read, 0u);
  EXPECT_EQ(linesIn(dir / kJournalFile), 0u);
}

TEST(Journal, ATornLineEndsWhatIsReadAndIsCutOffBeforeTheRestartAppends) {
  test::TempDir dir;
  Journal(dir.path(), false).append(twoKeyframesAndAnEdge(), frames(0, 10));
  {
    std::ofstream torn(dir / kJournalFile, std::ios::app);
    torn << "F 10 0.33333 0 0 1 0 0";  // killed in the middle of a line: no newline, fields missing
  }
  {
    Journal restarted(dir.path(), true);
    EXPECT_EQ(restarted.contents().lines_read, 13u);
    EXPECT_EQ(restarted.contents().frames.size(), 10u);
    restarted.append({}, frames(10, 5));
  }
  const JournalContents read = readJournal(dir / kJournalFile);
  EXPECT_EQ(read.lines_read, 18u);
  ASSERT_EQ(read.frames.size(), 15u);
  EXPECT_EQ(read.frames.back().frame_id, 14);
}

TEST(Journal, AnUnreadableLineInTheMiddleEndsWhatIsRead) {
  test::TempDir dir;
  Journal(dir.path(), false).append(twoKeyframesAndAnEdge(), frames(0, 3));
  {
    std::ofstream bad(dir / kJournalFile, std::ios::app);
    bad << "F 3 nan 0 0 1 0 0 0 0 1 0 0 0 0 1 0\n";  // a NaN timestamp
  }
  Journal(dir.path(), true).append({}, frames(4, 2));
  const JournalContents read = readJournal(dir / kJournalFile);
  EXPECT_EQ(read.frames.size(), 5u);  // the NaN line is cut off; what was appended after is there
  EXPECT_EQ(read.frames.back().frame_id, 5);
}

TEST(Journal, WithoutAnOutFolderNothingIsWritten) {
  Journal none("", true);
  none.append(twoKeyframesAndAnEdge(), frames(0, 3));
  EXPECT_EQ(none.contents().lines_read, 0u);
}

}  // namespace
}  // namespace rekon::optimiser
