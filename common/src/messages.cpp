#include "rekon/common/messages.hpp"

#include <cmath>

namespace rekon {

rekon_msgs::pose_t toMsg(const Pose& pose) {
  rekon_msgs::pose_t m;
  const Eigen::Quaterniond q(pose.linear());
  for (int i = 0; i < 3; ++i) m.t[i] = pose.translation()[i];
  m.q[0] = q.x();
  m.q[1] = q.y();
  m.q[2] = q.z();
  m.q[3] = q.w();
  return m;
}

std::optional<Pose> fromMsg(const rekon_msgs::pose_t& m) {
  for (double v : m.t) {
    if (!std::isfinite(v)) return std::nullopt;
  }
  for (double v : m.q) {
    if (!std::isfinite(v)) return std::nullopt;
  }
  const Eigen::Quaterniond q(m.q[3], m.q[0], m.q[1], m.q[2]);
  if (std::abs(q.norm() - 1.0) > 1e-3) return std::nullopt;
  return poseFromQuatTrans(q, Eigen::Vector3d(m.t[0], m.t[1], m.t[2]));
}

void toArray(const Eigen::Matrix<double, 6, 6>& m, double out[36]) {
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) out[r * 6 + c] = m(r, c);
  }
}

std::optional<Eigen::Matrix<double, 6, 6>> matrix6FromArray(const double in[36]) {
  Eigen::Matrix<double, 6, 6> m;
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) m(r, c) = in[r * 6 + c];
  }
  if (!m.allFinite()) return std::nullopt;
  return m;
}

void setIntrinsics(const Intrinsics& k, rekon_msgs::frame_t* msg) {
  msg->width = k.width;
  msg->height = k.height;
  msg->fx = k.fx;
  msg->fy = k.fy;
  msg->cx = k.cx;
  msg->cy = k.cy;
  msg->depth_scale = k.depth_scale;
}

Intrinsics intrinsicsOf(const rekon_msgs::frame_t& msg) {
  Intrinsics k;
  k.width = msg.width;
  k.height = msg.height;
  k.fx = msg.fx;
  k.fy = msg.fy;
  k.cx = msg.cx;
  k.cy = msg.cy;
  k.depth_scale = msg.depth_scale;
  k.validate("frame " + std::to_string(msg.frame_id));
  return k;
}

}  // namespace rekon
