// The optimiser's journal (services/optimiser/node/journal.hpp, in the
// format of rekon/common/record_journal.hpp): what is appended comes back in
// order, a first instance starts it empty, and a record torn by a kill ends
// what is read and is cut off before the restart appends.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>
#include <variant>

#include "frame_ids.hpp"
#include "journal.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/record_journal.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"
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

// Poses go through the bus's pose_t (a quaternion) as they did on their way
// in: the same to rounding, not to the bit.
bool samePose(const Pose& a, const Pose& b) { return (a.matrix() - b.matrix()).cwiseAbs().maxCoeff() < 1e-14; }

TEST(Journal, WhatIsAppendedComesBackExactlyInOrder) {
  test::TempDir dir;
  const auto items = twoKeyframesAndAnEdge();
  const auto written = frames(0, 40);
  Journal(dir.path(), false).append(items, written);
  const Journal again(dir.path(), true);
  const JournalContents& read = again.contents();
  EXPECT_EQ(read.records_read, 43u);
  ASSERT_EQ(read.items.size(), 3u);
  EXPECT_EQ(std::get<KeyframeIn>(read.items[1]).id, 1);
  EXPECT_TRUE(samePose(std::get<KeyframeIn>(read.items[1]).pose_world, std::get<KeyframeIn>(items[1]).pose_world));
  const auto& c = std::get<Constraint>(read.items[2]);
  const auto& want = std::get<Constraint>(items[2]);
  EXPECT_EQ(c.kind, EdgeKind::Loop);
  EXPECT_TRUE(samePose(c.relative, want.relative));
  EXPECT_EQ(c.information, want.information);  // doubles as they are
  ASSERT_EQ(read.frames.size(), written.size());
  for (size_t i = 0; i < written.size(); ++i) {
    EXPECT_EQ(read.frames[i].frame_id, written[i].frame_id);
    EXPECT_EQ(read.frames[i].timestamp, written[i].timestamp);
    EXPECT_EQ(read.frames[i].keyframe_id, written[i].keyframe_id);
    EXPECT_EQ(read.frames[i].lost, written[i].lost);
    EXPECT_TRUE(samePose(read.frames[i].pose_in_keyframe, written[i].pose_in_keyframe));
  }
}

// The final step's trajectory (issue 49): the tracked frames read back from
// the file instead of held by the inbox all run, once each, by id, the
// killed instance's and the restart's together.
TEST(Journal, TrackedFramesComeBackFromTheFileOnceEachById) {
  test::TempDir dir;
  Journal(dir.path(), false).append(twoKeyframesAndAnEdge(), frames(20, 30));
  Journal restart(dir.path(), true);
  restart.forgetContents();
  std::vector<TrackedFrame> late = frames(0, 25);  // replayed: 20-24 are in the file already
  restart.append({}, late);
  const std::vector<TrackedFrame> read = restart.trackedFrames();
  ASSERT_EQ(read.size(), 50u);
  for (size_t i = 0; i < read.size(); ++i) {
    EXPECT_EQ(read[i].frame_id, static_cast<int64_t>(i));
    EXPECT_EQ(read[i].lost, read[i].frame_id % 7 == 3);
    EXPECT_TRUE(samePose(read[i].pose_in_keyframe, turned(0.001 * static_cast<double>(i), 0.002)));
  }
  EXPECT_TRUE(Journal("", false).trackedFrames().empty());  // no out dir: no journal (the inbox holds them)
}

// The inbox's frame ids as runs: in order, out of order, repeated.
TEST(FrameIds, RunsJoinAndRepeatsAreRefused) {
  FrameIds ids;
  for (int64_t id = 0; id < 1000; ++id) EXPECT_TRUE(ids.insert(id));
  EXPECT_EQ(ids.runs(), 1u);
  EXPECT_TRUE(ids.insert(1001));
  EXPECT_TRUE(ids.insert(1003));
  EXPECT_EQ(ids.runs(), 3u);
  EXPECT_TRUE(ids.insert(1002));  // joins 1001 and 1003
  EXPECT_EQ(ids.runs(), 2u);
  EXPECT_TRUE(ids.insert(1000));  // joins everything
  EXPECT_EQ(ids.runs(), 1u);
  EXPECT_TRUE(ids.insert(-5));
  EXPECT_TRUE(ids.insert(-6));    // extends a run downwards
  EXPECT_EQ(ids.runs(), 2u);
  for (int64_t id : {0, 500, 1003, -5, -6}) EXPECT_FALSE(ids.insert(id)) << id;
  EXPECT_TRUE(ids.contains(1002));
  EXPECT_FALSE(ids.contains(1004));
  EXPECT_FALSE(ids.contains(-1));
  EXPECT_EQ(ids.size(), 1006u);
}

TEST(Journal, AFirstInstanceStartsItEmpty) {
  test::TempDir dir;
  Journal(dir.path(), false).append(twoKeyframesAndAnEdge(), frames(0, 10));
  const Journal fresh(dir.path(), false);
  EXPECT_EQ(fresh.contents().records_read, 0u);
  EXPECT_TRUE(readRecordJournal(dir / kJournalFile).records.empty());
}

TEST(Journal, ATornRecordEndsWhatIsReadAndIsCutOffBeforeTheRestartAppends) {
  test::TempDir dir;
  Journal(dir.path(), false).append(twoKeyframesAndAnEdge(), frames(0, 11));
  // Killed in the middle of the last record: its last 9 bytes never written.
  std::filesystem::resize_file(dir / kJournalFile, std::filesystem::file_size(dir / kJournalFile) - 9);
  {
    Journal restarted(dir.path(), true);
    EXPECT_EQ(restarted.contents().records_read, 13u);
    EXPECT_EQ(restarted.contents().frames.size(), 10u);
    restarted.append({}, frames(10, 5));
  }
  const JournalContents read = readJournal(dir / kJournalFile);
  EXPECT_EQ(read.records_read, 18u);
  ASSERT_EQ(read.frames.size(), 15u);
  EXPECT_EQ(read.frames.back().frame_id, 14);
}

TEST(Journal, AnUnreadableRecordInTheMiddleEndsWhatIsRead) {
  test::TempDir dir;
  Journal(dir.path(), false).append(twoKeyframesAndAnEdge(), frames(0, 3));
  {
    // Whole and checksummed, but a tracked frame with a NaN timestamp.
    RecordJournal bad(dir / kJournalFile, true);
    rekon_msgs::tracked_frame_t f{};
    f.frame_id = 3;
    f.timestamp = std::nan("");
    f.pose_in_keyframe = toMsg(Pose::Identity());
    bad.append(kTrackedFrameRecord, f);
  }
  Journal(dir.path(), true).append({}, frames(4, 2));
  const JournalContents read = readJournal(dir / kJournalFile);
  EXPECT_EQ(read.frames.size(), 5u);  // the NaN record is cut off; what was appended after is there
  EXPECT_EQ(read.frames.back().frame_id, 5);
}

rekon_msgs::graph_update_t update(int64_t version, bool final, const std::vector<int64_t>& ids) {
  rekon_msgs::graph_update_t m{};
  m.version = version;
  m.final_update = final;
  m.num_keyframes = static_cast<int32_t>(ids.size());
  m.keyframe_ids = ids;
  for (int64_t id : ids) m.poses.push_back(toMsg(turned(0.1 * static_cast<double>(id), 0.01)));
  return m;
}

// The newest version noted comes back, and the newest final update whole.
TEST(Journal, NotedGraphUpdatesComeBackAsTheNewestVersionAndTheFinalOneWhole) {
  test::TempDir dir;
  {
    Journal journal(dir.path(), false);
    journal.noteUpdate(update(3, false, {0, 1}));
    journal.append(twoKeyframesAndAnEdge(), frames(0, 2));
    journal.noteUpdate(update(40, true, {0, 1}));
    journal.noteUpdate(update(41, false, {0, 1}));
  }
  const Journal again(dir.path(), true);
  EXPECT_EQ(again.contents().newest_version, 41);
  EXPECT_EQ(again.contents().items.size(), 3u);
  ASSERT_TRUE(again.contents().final_update.has_value());
  const rekon_msgs::graph_update_t& final_update = *again.contents().final_update;
  EXPECT_EQ(final_update.version, 40);
  EXPECT_EQ(final_update.keyframe_ids, (std::vector<int64_t>{0, 1}));
  EXPECT_EQ(final_update.poses[1].t[0], update(40, true, {0, 1}).poses[1].t[0]);
}

TEST(Journal, WithoutAnOutFolderNothingIsWritten) {
  Journal none("", true);
  none.append(twoKeyframesAndAnEdge(), frames(0, 3));
  EXPECT_EQ(none.contents().records_read, 0u);
}

}  // namespace
}  // namespace rekon::optimiser
