// The named scenes: their geometry, materials and camera trajectories.
#include <cmath>
#include <numbers>

#include "analytic_scene.hpp"
#include "motion.hpp"
#include "scene_parts.hpp"
#include "sensor_noise.hpp"

namespace rekon::synth {
namespace {
using namespace parts;

// ---------------------------------------------------------------- tabletop

constexpr int kTabletopFrames = 90;

std::unique_ptr<AnalyticScene> tabletop() {
  SceneModel m;
  m.shell = shell({-2, -2, 0}, {2, 2, 2.5f}, kWallWarm, kWallCool, kWallCool, kWallWarm, kFloor, kCeiling);
  auto& p = m.primitives;
  addTable(&p, 0, 0, 0.6f, 0.45f, 0.72f, 0.0f, kWood);
  const float top = 0.72f;
  p.push_back(makeBox({-0.2f, 0.1f, top + 0.1f}, {0.12f, 0.08f, 0.1f}, 0.4f, kRed));
  p.push_back(makeCylinder({0.2f, 0.15f, top}, 0.05f, 0.18f, kGreen));
  p.push_back(makeSphere({0.05f, -0.15f, top + 0.08f}, 0.08f, kYellow));
  p.push_back(makeBox({0.32f, -0.2f, top + 0.05f}, {0.08f, 0.1f, 0.05f}, -0.3f, kBlue));
  p.push_back(makeCylinder({-0.35f, -0.22f, top}, 0.07f, 0.1f, kPurple));
  p.push_back(makeBox({0, 1.8f, 0.6f}, {0.8f, 0.2f, 0.6f}, 0.0f, kMetal));
  p.push_back(makeBox({1.5f, 1.3f, 0.3f}, {0.3f, 0.3f, 0.3f}, 0.3f, kPoster));
  p.push_back(makeBox({-1.985f, 0.0f, 1.4f}, {0.015f, 0.5f, 0.35f}, 0.0f, kPoster));

  auto trajectory = [](int frames, uint64_t seed) {
    Rng rng(mixSeed(seed, 0x7AB1Eull));
    const double a1 = 2 * kPi * rng.uniform(), a2 = 2 * kPi * rng.uniform(), a3 = 2 * kPi * rng.uniform();
    const double period = 2.0 * kTabletopFrames / kFrameRateHz;  // one sweep there in the default length
    const Shake shake(seed, period, 0.002, 0.003);
    return sample(frames, [&](double t) {
      // Sweep 40 degrees around the table at 1 m, looking at its centre.
      const double phi = -0.5 * kPi - 20.0 * kDeg * std::cos(2 * kPi * t / period);
      const Eigen::Vector3d pos(1.0 * std::cos(phi), 1.0 * std::sin(phi), 1.25 + 0.05 * std::sin(2 * kPi * t / period + a1));
      const Eigen::Vector3d target(0.04 * std::sin(4 * kPi * t / period + a2), 0.04 * std::cos(2 * kPi * t / period + a3), 0.78);
      const Eigen::Vector3d d = target - pos;
      const double yaw = std::atan2(d.y(), d.x()), pitch = std::atan2(d.z(), d.head<2>().norm());
      return shaken(shake, t, pos, yaw, pitch, 1.5 * kDeg * std::sin(2 * kPi * t / period + a3));
    });
  };
  return std::make_unique<AnalyticScene>("tabletop", std::move(m), palette(), kTabletopFrames, 0.02, trajectory);
}

// ---------------------------------------------------------------- room

constexpr int kRoomFrames = 600;

std::unique_ptr<AnalyticScene> room() {
  SceneModel m;
  m.shell = shell({-3, -2.5f, 0}, {3, 2.5f, 2.7f}, kWallWarm, kWallCool, kWallCool, kWallWarm, kFloor, kCeiling);
  auto& p = m.primitives;
  addTable(&p, 1.9f, -1.4f, 0.6f, 0.4f, 0.74f, 0.1f, kWood);
  p.push_back(makeBox({1.7f, -1.3f, 0.74f + 0.075f}, {0.15f, 0.1f, 0.075f}, 0.5f, kRed));
  p.push_back(makeCylinder({2.1f, -1.5f, 0.74f}, 0.06f, 0.2f, kGreen));
  p.push_back(makeSphere({1.95f, -1.15f, 0.74f + 0.1f}, 0.1f, kYellow));
  p.push_back(makeBox({-2.8f, 0.5f, 0.9f}, {0.2f, 0.8f, 0.9f}, 0.0f, kMetal));            // cabinet
  p.push_back(makeBox({-0.3f, 2.1f, 0.225f}, {1.0f, 0.4f, 0.225f}, 0.0f, kBlue));          // sofa seat
  p.push_back(makeBox({-0.3f, 2.4f, 0.55f}, {1.0f, 0.1f, 0.55f}, 0.0f, kBlue));            // sofa back
  p.push_back(makeBox({-1.4f, 2.1f, 0.3f}, {0.1f, 0.4f, 0.3f}, 0.0f, kPurple));            // armrests
  p.push_back(makeBox({0.8f, 2.1f, 0.3f}, {0.1f, 0.4f, 0.3f}, 0.0f, kPurple));
  p.push_back(makeBox({2.5f, 2.0f, 0.25f}, {0.25f, 0.25f, 0.25f}, 0.2f, kRed));            // box stack
  p.push_back(makeBox({2.45f, 1.95f, 0.675f}, {0.175f, 0.175f, 0.175f}, -0.4f, kGreen));
  p.push_back(makeCylinder({2.2f, 0.6f, 0.0f}, 0.15f, 2.7f, kPoster));                    // pillar
  p.push_back(makeCylinder({-1.6f, -1.75f, 0.0f}, 0.22f, 0.6f, kPurple));                 // bin
  p.push_back(makeSphere({0.3f, -2.0f, 0.25f}, 0.25f, kGreen));                           // ball
  p.push_back(makeCylinder({-2.4f, 1.9f, 0.0f}, 0.025f, 1.5f, kMetal));                   // floor lamp
  p.push_back(makeSphere({-2.4f, 1.9f, 1.62f}, 0.15f, kYellow));
  p.push_back(makeBox({-1.0f, -2.49f, 1.5f}, {0.45f, 0.015f, 0.32f}, 0.0f, kPoster));     // poster
  p.push_back(makeBox({2.985f, -0.5f, 1.4f}, {0.015f, 0.5f, 0.35f}, 0.0f, kPurple));      // painting
  p.push_back(makeBox({-2.2f, -2.3f, 0.4f}, {0.6f, 0.2f, 0.4f}, 0.0f, kWood));            // low shelf
  p.push_back(makeBox({-2.985f, -1.5f, 1.0f}, {0.015f, 0.45f, 1.0f}, 0.0f, kWood));       // door

  auto trajectory = [](int frames, uint64_t seed) {
    Rng rng(mixSeed(seed, 0x200Dull));
    double ph[5];
    for (double& x : ph) x = 2 * kPi * rng.uniform();
    // One loop per default sequence: the last default frame is the first pose again.
    const double period = (kRoomFrames - 1) / kFrameRateHz;
    const Shake shake(seed, period, 0.002, 0.003);
    const double a = 1.1, b = 0.9;
    return sample(frames, [&](double t) {
      const double phi = 2 * kPi * t / period;
      const Eigen::Vector3d pos(a * std::cos(phi), b * std::sin(phi), 1.4 + 0.1 * std::sin(2 * phi + ph[0]));
      // Walk anticlockwise, looking 50 degrees outwards of the walking direction.
      const double heading = std::atan2(b * std::cos(phi), -a * std::sin(phi));
      const double yaw = heading - 50.0 * kDeg + 6.0 * kDeg * std::sin(3 * phi + ph[1]);
      const double pitch = -18.0 * kDeg + 5.0 * kDeg * std::sin(2 * phi + ph[2]);
      const double roll = 2.0 * kDeg * std::sin(phi + ph[3]);
      return shaken(shake, t, pos, yaw, pitch, roll);
    });
  };
  return std::make_unique<AnalyticScene>("room", std::move(m), palette(), kRoomFrames, 0.02, trajectory);
}

}  // namespace

std::unique_ptr<AnalyticScene> makeTabletopScene() { return tabletop(); }
std::unique_ptr<AnalyticScene> makeRoomScene() { return room(); }

}  // namespace rekon::synth
