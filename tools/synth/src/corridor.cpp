// The corridor: 36 m long, furnished along both walls, walked 30.5 m out, a
// U-turn at the far end, and 30.5 m back (about 63 m of path), for streaming
// and drift tests. With more laps the walker turns at the near end too and
// goes round the same oval again (64.2 m a lap), for long runs that revisit
// every place.
#include <cmath>

#include "analytic_scene.hpp"
#include "scene_parts.hpp"
#include "sensor_noise.hpp"

namespace rekon::synth {
namespace {
using namespace parts;

constexpr float kLengthLo = -2.0f, kLengthHi = 34.0f, kHalfWidth = 1.25f, kHeight = 2.6f;
// Path: straight out along +x, a U-turn of kTurnM (heading 0 -> pi), straight
// back; each further lap first turns at the near end (heading pi -> 2 pi, the
// same counter-clockwise sense, back into the outbound lane).
constexpr double kStartX = 0.0, kStartY = -0.45;
constexpr double kOutM = 30.5, kTurnM = 1.6;
constexpr double kLegM = kOutM + kTurnM;  // a straight leg and the turn after it
// Out, turn, back; then per further lap turn, out, turn, back.
double pathM(int laps) { return 2 * kOutM + kTurnM + (laps - 1) * 2 * kLegM; }
int turns(int laps) { return 2 * laps - 1; }
double turnStart(int j) { return kOutM + j * kLegM; }
constexpr double kCruiseMps = 0.45, kTurnMps = 0.12;
constexpr double kSlowZoneM = 2.5;   // speed blends to kTurnMps over this distance before/after the turn
constexpr double kAccelMps2 = 0.25;  // starting and stopping
constexpr double kHoldS = 0.5;       // standing still at the end
constexpr double kStepS = 1.0 / 600.0;

double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}
double smootherstep(double x) {
  const double t = std::clamp(x, 0.0, 1.0);
  return t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
}

// 1 inside a U-turn, 0 beyond kSlowZoneM from every one.
double turnWeight(double s, int laps) {
  double w = 0.0;
  for (int j = 0; j < turns(laps); ++j) {
    const double before = turnStart(j) - s, after = s - (turnStart(j) + kTurnM);
    const double d = std::max({before, after, 0.0});
    w = std::max(w, 1.0 - smoothstep(0.0, kSlowZoneM, d));
  }
  return w;
}

double heading(double s, int laps) {
  double h = 0.0;
  for (int j = 0; j < turns(laps); ++j) h += kPi * smootherstep((s - turnStart(j)) / kTurnM);
  return h;
}

double speed(double s, double t, int laps) {
  const double v = kCruiseMps + (kTurnMps - kCruiseMps) * turnWeight(s, laps);
  return std::min({v, kAccelMps2 * t + 0.02, std::sqrt(2.0 * kAccelMps2 * std::max(0.0, pathM(laps) - s))});
}

struct PathState {
  double t, x, y, s, turn;
};

// Integrates the walk (speed profile along the path, heading from the path) at kStepS.
std::vector<PathState> walk(int frames, int laps) {
  std::vector<PathState> out;
  double t = 0, x = kStartX, y = kStartY, s = 0;
  int next_frame = 0;
  const double path = pathM(laps);
  while (next_frame < frames) {
    if (t + 1e-9 >= next_frame / kFrameRateHz) {
      out.push_back({next_frame / kFrameRateHz, x, y, s, turnWeight(s, laps)});
      ++next_frame;
    }
    const double ds = std::min(speed(s, t, laps) * kStepS, path - s);
    const double psi = heading(s + 0.5 * ds, laps);
    x += ds * std::cos(psi);
    y += ds * std::sin(psi);
    s += ds;
    t += kStepS;
  }
  return out;
}

int corridorDefaultFrames(int laps) {
  // Walk until the end of the path, then hold still for kHoldS.
  double t = 0, s = 0;
  const double path = pathM(laps);
  while (s < path - 1e-4 && t < 1000.0 * laps) {
    s += std::min(speed(s, t, laps) * kStepS, path - s);
    t += kStepS;
  }
  return static_cast<int>(std::ceil((t + kHoldS) * kFrameRateHz));
}

SceneModel corridorModel() {
  SceneModel m;
  m.shell = shell({kLengthLo, -kHalfWidth, 0}, {kLengthHi, kHalfWidth, kHeight}, kWallCool, kWallWarm, kWallWarm,
                  kWallCool, kFloor, kCeiling);
  auto& p = m.primitives;
  const int object_mats[] = {kRed, kGreen, kBlue, kYellow, kMetal, kPurple, kPoster, kWood};
  Rng rng(0xC0221D0ull);  // the geometry is fixed; seeds change only motion and noise
  auto mat = [&] { return object_mats[rng.next() % 8]; };
  auto uni = [&](double a, double b) { return static_cast<float>(a + (b - a) * rng.uniform()); };
  for (int side = -1; side <= 1; side += 2) {
    const float wall = side * kHalfWidth;
    float x = 1.0f + uni(0.0, 1.0);
    while (x < 29.5f) {
      const double kind = rng.uniform();
      float width = 0.0f;
      if (kind < 0.35) {  // cabinet, sometimes with a ball on top
        const float d = uni(0.25, 0.4), w = uni(0.5, 1.2), h = uni(0.7, 1.9);
        p.push_back(makeBox({x + 0.5f * w, wall - side * 0.5f * d, 0.5f * h}, {0.5f * w, 0.5f * d, 0.5f * h}, 0.0f, mat()));
        if (h < 1.2f && rng.uniform() < 0.5) {
          const float r = uni(0.08, 0.15);
          p.push_back(makeSphere({x + 0.5f * w, wall - side * 0.5f * d, h + r}, r, mat()));
        }
        width = w;
      } else if (kind < 0.55) {  // pillar in the wall, floor to ceiling
        const float w = uni(0.3, 0.45);
        p.push_back(makeBox({x + 0.5f * w, wall - side * 0.1f, 0.5f * kHeight}, {0.5f * w, 0.2f, 0.5f * kHeight}, 0.0f, mat()));
        width = w;
      } else if (kind < 0.75) {  // bin or drum
        const float r = uni(0.12, 0.22), h = uni(0.5, 1.1);
        p.push_back(makeCylinder({x + r, wall - side * (r + 0.05f), 0.0f}, r, h, mat()));
        width = 2 * r;
      } else {  // picture on the wall
        const float w = uni(0.6, 1.0), h = uni(0.4, 0.7), z = uni(1.2, 1.8);
        p.push_back(makeBox({x + 0.5f * w, wall - side * 0.015f, z}, {0.5f * w, 0.015f, 0.5f * h}, 0.0f, mat()));
        width = w;
      }
      x += width + uni(0.5, 1.6);
    }
  }
  for (float x = 1.5f; x < kLengthHi - 1.0f; x += 3.0f) {  // ceiling lamps
    p.push_back(makeBox({x, 0.0f, kHeight - 0.05f}, {0.3f, 0.1f, 0.05f}, 0.0f, kYellow));
  }
  p.push_back(makeBox({kLengthHi - 0.2f, 0.0f, 1.0f}, {0.2f, 0.6f, 1.0f}, 0.0f, kMetal));  // cabinet at the far end
  p.push_back(makeSphere({kLengthHi - 0.6f, 0.8f, 0.3f}, 0.3f, kRed));
  return m;
}

Trajectory corridorTrajectory(int frames, uint64_t seed, int laps) {
  Rng rng(mixSeed(seed, 0xC0221ull));
  double ph[5];
  for (double& x : ph) x = 2 * kPi * rng.uniform();
  // The shake's period stays that of one lap, so every lap count shakes alike.
  const int default_frames = corridorDefaultFrames(1);
  const Shake shake(seed, default_frames / kFrameRateHz, 0.002, 0.003);
  const auto states = walk(frames, laps);
  Trajectory out;
  out.reserve(states.size());
  for (const auto& st : states) {
    const double t = st.t, look = 1.0 - st.turn;  // no looking around during the U-turn
    const double yaw = heading(st.s, laps) + look * 15.0 * kDeg * std::sin(2 * kPi * t / 9.0 + ph[0]);
    const double pitch = -8.0 * kDeg + 4.0 * kDeg * std::sin(2 * kPi * t / 7.0 + ph[1]);
    const double roll = 1.5 * kDeg * std::sin(2 * kPi * t / 5.0 + ph[2]);
    const double z = 1.45 + 0.005 * std::sin(2 * kPi * 1.8 * t + ph[3]);
    out.push_back({t, shaken(shake, t, Eigen::Vector3d(st.x, st.y, z), yaw, pitch, roll)});
  }
  return out;
}

}  // namespace

std::unique_ptr<AnalyticScene> makeCorridorScene() {
  return std::make_unique<AnalyticScene>("corridor", corridorModel(), palette(), 0.03, corridorDefaultFrames,
                                         corridorTrajectory);
}

}  // namespace rekon::synth
