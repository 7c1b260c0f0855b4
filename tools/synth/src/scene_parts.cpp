#include <cmath>

#include "scene_parts.hpp"

namespace rekon::synth::parts {

namespace {
Material material(V3 a, V3 b, float checker, float checker_w, float stripes, float angle, float stripe_w, float noise_w,
                  uint32_t seed) {
  Material m;
  m.color_a = a;
  m.color_b = b;
  m.checker_period = checker;
  m.checker_weight = checker_w;
  m.stripe_period = stripes;
  m.stripe_cos = std::cos(angle);
  m.stripe_sin = std::sin(angle);
  m.stripe_weight = stripe_w;
  m.noise_weight = noise_w;
  m.seed = seed;
  return m;
}

}  // namespace

std::vector<Material> palette() {
  return {
      material({0.35f, 0.22f, 0.15f}, {0.95f, 0.88f, 0.75f}, 0.6f, 0.3f, 0.09f, 0.5f, 0.2f, 0.7f, 11),
      material({0.12f, 0.2f, 0.35f}, {0.8f, 0.85f, 0.95f}, 0.0f, 0.0f, 0.23f, 1.3f, 0.35f, 0.7f, 23),
      material({0.25f, 0.15f, 0.08f}, {0.85f, 0.65f, 0.4f}, 0.8f, 0.25f, 0.11f, 0.0f, 0.3f, 0.6f, 37),
      material({0.55f, 0.55f, 0.55f}, {0.98f, 0.98f, 0.95f}, 1.0f, 0.2f, 0.0f, 0.0f, 0.0f, 0.9f, 41),
      material({0.2f, 0.1f, 0.05f}, {0.7f, 0.45f, 0.25f}, 0.0f, 0.0f, 0.03f, 0.1f, 0.3f, 0.8f, 53),
      material({0.5f, 0.05f, 0.05f}, {0.98f, 0.8f, 0.6f}, 0.08f, 0.5f, 0.0f, 0.0f, 0.0f, 0.5f, 67),
      material({0.05f, 0.3f, 0.1f}, {0.75f, 0.95f, 0.6f}, 0.0f, 0.0f, 0.05f, 0.8f, 0.45f, 0.5f, 79),
      material({0.05f, 0.1f, 0.45f}, {0.7f, 0.8f, 1.0f}, 0.15f, 0.4f, 0.04f, -0.6f, 0.2f, 0.5f, 83),
      material({0.45f, 0.35f, 0.02f}, {1.0f, 0.95f, 0.5f}, 0.2f, 0.2f, 0.0f, 0.0f, 0.0f, 0.9f, 97),
      material({0.15f, 0.15f, 0.17f}, {0.85f, 0.85f, 0.9f}, 0.0f, 0.0f, 0.02f, 1.57f, 0.3f, 0.6f, 101),
      material({0.3f, 0.05f, 0.35f}, {0.95f, 0.75f, 0.95f}, 0.05f, 0.45f, 0.0f, 0.0f, 0.0f, 0.5f, 113),
      material({0.05f, 0.05f, 0.05f}, {0.95f, 0.95f, 0.95f}, 0.1f, 0.6f, 0.0f, 0.0f, 0.0f, 0.6f, 127),
  };
}

Shell shell(V3 lo, V3 hi, int mx0, int mx1, int my0, int my1, int floor, int ceiling) {
  Shell s;
  s.box = {lo, hi};
  const int m[6] = {mx0, mx1, my0, my1, floor, ceiling};
  for (int i = 0; i < 6; ++i) s.material[i] = m[i];
  return s;
}

void addTable(std::vector<Primitive>* out, float x, float y, float hx, float hy, float height, float yaw, int mat) {
  const float c = std::cos(yaw), s = std::sin(yaw), top = 0.02f, leg = 0.025f;
  out->push_back(makeBox({x, y, height - top}, {hx, hy, top}, yaw, mat));
  const float leg_h = 0.5f * (height - 2 * top);
  for (int i = 0; i < 4; ++i) {
    const float lx = ((i & 1) ? 1.0f : -1.0f) * (hx - 0.06f), ly = ((i & 2) ? 1.0f : -1.0f) * (hy - 0.06f);
    out->push_back(makeBox({x + c * lx - s * ly, y + s * lx + c * ly, leg_h}, {leg, leg, leg_h}, yaw, mat));
  }
}

Trajectory sample(int frames, const std::function<Pose(double)>& pose_at) {
  Trajectory out;
  out.reserve(static_cast<size_t>(std::max(frames, 0)));
  for (int i = 0; i < frames; ++i) {
    const double t = i / kFrameRateHz;
    out.push_back({t, pose_at(t)});
  }
  return out;
}

Pose shaken(const Shake& shake, double t, const Eigen::Vector3d& position, double yaw, double pitch, double roll) {
  Eigen::Vector3d dp, dr;
  shake.at(t, &dp, &dr);
  return lookPose(position + dp, yaw + dr.x(), pitch + dr.y(), roll + dr.z());
}

}  // namespace rekon::synth::parts
