// A session's files without a run: what the writer leaves opens with the same
// keyframes, poses and frames; what a killed writer leaves opens; damaged,
// foreign and newer sessions are refused with one line naming the file; the
// optimiser's graph in g2o's format.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>

#include "rekon/common/error.hpp"
#include "rekon/mapper/store/session.hpp"
#include "rekon/optimiser/g2o.hpp"
#include "test_support.hpp"

namespace rekon::store {
namespace {

namespace fs = std::filesystem;
using rekon::test::readText;

SessionInfo smallCamera() {
  SessionInfo info;
  info.camera.width = 32;
  info.camera.height = 24;
  info.camera.fx = info.camera.fy = 30.0;
  info.camera.cx = 15.5;
  info.camera.cy = 11.5;
  return info;
}

Pose poseAt(double x, double yaw) {
  Pose p = Pose::Identity();
  p.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(x, 0.1, -0.2);
  return p;
}

fusion::FusedKeyframe keyframe(int64_t id, int64_t anchor) {
  fusion::FusedKeyframe kf;
  kf.id = id;
  kf.anchor_keyframe_id = anchor;
  kf.pose_in_anchor = poseAt(0.01 * static_cast<double>(id), 0.02);
  kf.first_frame_id = 10 * id;
  kf.last_frame_id = 10 * id + 9;
  kf.frames = 10;
  kf.timestamp = 100.0 + static_cast<double>(id);
  kf.depth = cv::Mat(24, 32, CV_32F);
  kf.weight = cv::Mat(24, 32, CV_32F);
  kf.color = cv::Mat(24, 32, CV_8UC3);
  cv::RNG rng(static_cast<uint64_t>(id) + 1);  // the same images for the same id
  rng.fill(kf.depth, cv::RNG::UNIFORM, 0.5, 3.0);
  rng.fill(kf.weight, cv::RNG::UNIFORM, 0.0, 5.0);
  rng.fill(kf.color, cv::RNG::UNIFORM, 0, 255);
  return kf;
}

bool sameMat(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0.0;
}

// Three keyframes on two anchors, five frames, the anchors moved by a graph update.
void writeSession(const std::string& dir) {
  SessionWriter w(dir, smallCamera(), false);
  w.setAnchorPoses({{0, poseAt(0, 0)}, {1, poseAt(0.5, 0.1)}});
  for (int64_t f = 0; f < 5; ++f) w.addFrame({f, 100.0 + 0.1 * static_cast<double>(f), f < 3 ? 0 : 1, poseAt(0.01 * f, 0)});
  w.addKeyframe(keyframe(0, 0));
  w.addKeyframe(keyframe(1, 0));
  w.addKeyframe(keyframe(2, 1));
  w.setAnchorPoses({{0, poseAt(0, 0)}, {1, poseAt(0.6, 0.12)}});
}

TEST(SessionFiles, WhatTheWriterLeavesOpensWithTheSameKeyframesPosesAndFrames) {
  rekon::test::TempDir dir;
  writeSession(dir / "s");
  const Session s = Session::open(dir / "s");
  EXPECT_EQ(s.info().format_version, kSessionFormatVersion);
  EXPECT_EQ(s.info().camera.width, 32);
  EXPECT_DOUBLE_EQ(s.info().camera.cx, 15.5);
  ASSERT_EQ(s.keyframes().size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    const fusion::FusedKeyframe want = keyframe(static_cast<int64_t>(i), i < 2 ? 0 : 1);
    const fusion::FusedKeyframe got = s.load(i);
    EXPECT_EQ(got.id, want.id);
    EXPECT_EQ(got.anchor_keyframe_id, want.anchor_keyframe_id);
    EXPECT_EQ(got.last_frame_id, want.last_frame_id);
    EXPECT_TRUE(got.pose_in_anchor.isApprox(want.pose_in_anchor, 1e-8));
    EXPECT_TRUE(sameMat(got.depth, want.depth) && sameMat(got.weight, want.weight) && sameMat(got.color, want.color));
  }
  // The newest anchor poses place the keyframes.
  const auto world = s.worldPose(s.keyframes()[2]);
  ASSERT_TRUE(world);
  EXPECT_TRUE(world->isApprox(poseAt(0.6, 0.12) * keyframe(2, 1).pose_in_anchor, 1e-8));
  const auto frames = s.frames();
  ASSERT_EQ(frames.size(), 5u);
  EXPECT_EQ(frames[4].keyframe_id, 1);
  EXPECT_TRUE(frames[4].pose_in_keyframe.isApprox(poseAt(0.04, 0), 1e-8));
}

// A killed writer: images without metadata (in flight) are left out, a
// frames.txt line cut short is skipped, and a restarted writer ends it
// before appending.
TEST(SessionFiles, WhatAKilledWriterLeavesOpensLosingOnlyWhatWasInFlight) {
  rekon::test::TempDir dir;
  writeSession(dir / "s");
  fs::copy_file(dir / "s/keyframes/kf_000002.rks", dir / "s/keyframes/kf_000007.rks");
  std::ofstream(dir / "s/keyframes/kf_000008.txt.tmp") << "8 1 80";
  std::ofstream(dir / "s/frames.txt", std::ios::app) << "5 100.5 1 0.1 0.2";
  EXPECT_EQ(Session::open(dir / "s").keyframes().size(), 3u);
  EXPECT_EQ(Session::open(dir / "s").frames().size(), 5u);
  {
    SessionWriter again(dir / "s", smallCamera(), true);  // a restarted mapper
    again.addFrame({6, 100.6, 1, poseAt(0.06, 0)});
  }
  const auto frames = Session::open(dir / "s").frames();
  ASSERT_EQ(frames.size(), 6u);
  EXPECT_EQ(frames.back().frame_id, 6);
}

// Every refusal is one line naming the file (or folder) and leaves the session as it was.
void expectRefused(const std::string& dir, const std::string& names) {
  try {
    Session::open(dir);
    ADD_FAILURE() << "opened " << dir;
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(names), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
  }
}

TEST(SessionFiles, DamagedForeignAndNewerSessionsAreRefusedWithOneLine) {
  rekon::test::TempDir dir;
  expectRefused(dir / "none", "no session.yaml");
  writeSession(dir / "s");
  const std::string yaml = readText(dir / "s/session.yaml");

  std::ofstream(dir / "s/session.yaml") << "format_version: 2\n";
  expectRefused(dir / "s", "newer than this rekon's 1");
  std::ofstream(dir / "s/session.yaml") << "format_version: [1\n";
  expectRefused(dir / "s", "session.yaml is damaged");
  std::ofstream(dir / "s/session.yaml") << yaml;

  fs::rename(dir / "s/keyframes/kf_000001.rks", dir / "kf1.rks");
  expectRefused(dir / "s", "kf_000001.rks is missing");
  fs::rename(dir / "kf1.rks", dir / "s/keyframes/kf_000001.rks");

  fs::resize_file(dir / "s/keyframes/kf_000001.rks", 1000);
  const Session s = Session::open(dir / "s");
  try {
    s.load(1);
    ADD_FAILURE() << "loaded a truncated keyframe";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("kf_000001.rks is truncated"), std::string::npos) << e.what();
  }

  std::ofstream(dir / "s/anchors.txt", std::ios::app) << "9 1 2 3 nan 0 0 1\n";
  expectRefused(dir / "s", "anchors.txt is damaged");

  // A new run never writes over a session, and one of another camera is refused even to a restart.
  try {
    SessionWriter w(dir / "s", smallCamera(), false);
    ADD_FAILURE() << "wrote over a session";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("already holds a session"), std::string::npos) << e.what();
  }
  SessionInfo other = smallCamera();
  other.camera.fx = 31.0;
  EXPECT_THROW(SessionWriter(dir / "s", other, true), Error);
  EXPECT_EQ(readText(dir / "s/session.yaml"), yaml);
}

// g2o: one vertex per keyframe, FIX for the anchor, one edge per constraint
// with the information in g2o's units (rotation x4, mixed x2).
TEST(SessionFiles, PoseGraphInG2oFormat) {
  optimiser::PoseGraph graph;
  graph.addKeyframe(0, poseAt(0, 0));
  graph.addKeyframe(1, poseAt(0.5, 0.1));
  optimiser::Constraint c;
  c.from_id = 0;
  c.to_id = 1;
  c.relative = poseAt(0, 0).inverse() * poseAt(0.5, 0.1);
  c.information = rekon::Matrix6d::Identity() * 100.0;
  c.information(0, 3) = c.information(3, 0) = 5.0;
  graph.addConstraint(c);
  const std::string g2o = optimiser::toG2o(graph);
  EXPECT_NE(g2o.find("VERTEX_SE3:QUAT 0 "), std::string::npos) << g2o;
  EXPECT_NE(g2o.find("VERTEX_SE3:QUAT 1 0.500000000 0.100000000 -0.200000000 "), std::string::npos) << g2o;
  EXPECT_NE(g2o.find("FIX 0\n"), std::string::npos) << g2o;
  const size_t edge = g2o.find("EDGE_SE3:QUAT 0 1 ");
  ASSERT_NE(edge, std::string::npos) << g2o;
  std::istringstream in(g2o.substr(edge + 18));
  std::vector<double> v;
  for (double x; in >> x;) v.push_back(x);
  ASSERT_EQ(v.size(), 7u + 21u);
  EXPECT_DOUBLE_EQ(v[7], 100.0);       // (x, x)
  EXPECT_DOUBLE_EQ(v[7 + 3], 2 * 5.0);  // (x, qx): mixed, x2
  EXPECT_DOUBLE_EQ(v[7 + 15], 400.0);  // (qx, qx): rotation, x4
  EXPECT_DOUBLE_EQ(v[7 + 20], 400.0);  // (qz, qz)
}

}  // namespace
}  // namespace rekon::store
