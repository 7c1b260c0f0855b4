#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "rekon/common/bus.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace {

template <class Msg>
std::string encode(Msg msg) {
  msg.schema_version = rekon::kSchemaVersion;
  std::string buf(static_cast<size_t>(msg.getEncodedSize()), '\0');
  msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
  return buf;
}

template <class Msg>
bool decodes(const std::string& buf, Msg* out) {
  std::string why;
  return rekon::decodeMessage(buf.data(), static_cast<int>(buf.size()), out, &why);
}

rekon_msgs::graph_update_t graphOf(int n) {
  rekon_msgs::graph_update_t g{};
  g.version = 7;
  g.num_keyframes = n;
  for (int i = 0; i < n; ++i) {
    g.keyframe_ids.push_back(i * 3);
    g.poses.push_back(rekon::toMsg(rekon::poseFromQuatTrans(Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitY())),
                                                            Eigen::Vector3d(i, 0, 0))));
  }
  return g;
}

}  // namespace

TEST(Messages, FrameRoundTripsWithInlineImages) {
  rekon_msgs::frame_t f{};
  f.frame_id = 42;
  f.timestamp = 1.5;
  rekon::setIntrinsics(rekon::Intrinsics{}, &f);
  f.depth_png = {1, 2, 3};
  f.depth_png_size = 3;
  f.color = {9, 8};
  f.color_size = 2;
  f.color_format = "jpeg";
  rekon_msgs::frame_t g;
  ASSERT_TRUE(decodes(encode(f), &g));
  EXPECT_EQ(g.frame_id, 42);
  EXPECT_EQ(g.depth_png, f.depth_png);
  EXPECT_EQ(g.color, f.color);
  EXPECT_EQ(rekon::intrinsicsOf(g).fx, 525.0);
}

TEST(Messages, GraphUpdateRoundTripsEveryPose) {
  const auto g = graphOf(5);
  rekon_msgs::graph_update_t h;
  ASSERT_TRUE(decodes(encode(g), &h));
  ASSERT_EQ(h.num_keyframes, 5);
  const auto pose = rekon::fromMsg(h.poses[4]);
  ASSERT_TRUE(pose.has_value());
  EXPECT_NEAR(pose->translation().x(), 4.0, 1e-12);
  EXPECT_EQ(h.keyframe_ids[4], 12);
}

TEST(Messages, TrackedFrameAndConstraintRoundTrip) {
  rekon_msgs::tracked_frame_t t{};
  t.frame_id = 3;
  t.keyframe_id = 1;
  t.state = rekon_msgs::tracked_frame_t::STATE_LOST;
  t.pose_in_keyframe = rekon::toMsg(rekon::Pose::Identity());
  rekon::toArray(Eigen::Matrix<double, 6, 6>::Identity() * 2, t.covariance);
  rekon_msgs::tracked_frame_t u;
  ASSERT_TRUE(decodes(encode(t), &u));
  EXPECT_EQ(u.state, rekon_msgs::tracked_frame_t::STATE_LOST);
  EXPECT_EQ(rekon::matrix6FromArray(u.covariance)->trace(), 12.0);

  rekon_msgs::constraint_t c{};
  c.kind = rekon_msgs::constraint_t::KIND_LOOP;
  c.from_id = 1;
  c.to_id = 9;
  c.relative = rekon::toMsg(rekon::Pose::Identity());
  rekon_msgs::constraint_t d;
  ASSERT_TRUE(decodes(encode(c), &d));
  EXPECT_EQ(d.to_id, 9);
}

TEST(Messages, WrongFingerprintIsRejected) {
  rekon_msgs::heartbeat_t hb{};
  hb.service = "x";
  rekon_msgs::graph_update_t g;
  EXPECT_FALSE(decodes(encode(hb), &g));
}

TEST(Messages, TruncatedBufferIsRejectedAtEveryLength) {
  const std::string full = encode(graphOf(3));
  for (size_t n = 0; n < full.size(); ++n) {
    rekon_msgs::graph_update_t g;
    EXPECT_FALSE(decodes(full.substr(0, n), &g)) << "accepted a buffer cut to " << n << " bytes";
  }
}

TEST(Messages, AbsurdArrayLengthIsRejectedWithoutCrashing) {
  std::string buf = encode(graphOf(1));
  // num_keyframes follows fingerprint(8) schema_version(4) version(8) final_update(1).
  const size_t offset = 8 + 4 + 8 + 1;
  for (uint32_t absurd : {0x7fffffffu, 0x80000000u, 0xffffffffu, 1000000u}) {
    buf[offset] = static_cast<char>(absurd >> 24);
    buf[offset + 1] = static_cast<char>(absurd >> 16);
    buf[offset + 2] = static_cast<char>(absurd >> 8);
    buf[offset + 3] = static_cast<char>(absurd);
    rekon_msgs::graph_update_t g;
    EXPECT_FALSE(decodes(buf, &g)) << "accepted num_keyframes = " << absurd;
  }
}

TEST(Messages, UnknownSchemaVersionIsRejected) {
  auto g = graphOf(1);
  std::string buf = encode(g);
  buf[8 + 3] = 99;  // schema_version's low byte (big-endian int32 after the fingerprint)
  rekon_msgs::graph_update_t h;
  std::string why;
  EXPECT_FALSE(rekon::decodeMessage(buf.data(), static_cast<int>(buf.size()), &h, &why));
  EXPECT_NE(why.find("schema_version"), std::string::npos) << why;
}

TEST(Messages, NaNPoseAndBadIntrinsicsAreRejected) {
  rekon_msgs::pose_t p = rekon::toMsg(rekon::Pose::Identity());
  p.t[1] = std::nan("");
  EXPECT_FALSE(rekon::fromMsg(p).has_value());
  p = rekon::toMsg(rekon::Pose::Identity());
  p.q[3] = 5.0;  // far from a unit quaternion
  EXPECT_FALSE(rekon::fromMsg(p).has_value());
  rekon_msgs::frame_t f{};
  rekon::setIntrinsics(rekon::Intrinsics{}, &f);
  f.fx = INFINITY;
  EXPECT_THROW(rekon::intrinsicsOf(f), rekon::Error);
  f.fx = 525;
  f.width = -640;
  EXPECT_THROW(rekon::intrinsicsOf(f), rekon::Error);
}
