// The building: one storey of 40 x 24 m, four rooms along each long side,
// a corridor in front of each row of rooms, three corridors across and four
// inner rooms between them, 2.7 m high; every room has at least two doors,
// so the corridors and the rooms form many loops. Each wall piece has its
// own material (its own noise), so no two walls look alike. The camera walks
// three different laps (through the south rooms and across; through the
// north rooms and across; a serpentine through every inner room), over and
// over: a 60-minute walk passes every part about four times. For long runs
// (issue 49): at 1 cm voxels the map is several times the mapper's budgets.
#include <cmath>

#include "analytic_scene.hpp"
#include "building_path.hpp"
#include "scene_parts.hpp"
#include "sensor_noise.hpp"

namespace rekon::synth {
namespace {
using namespace parts;

constexpr float kSizeX = 40.0f, kSizeY = 24.0f, kHeight = 2.7f;
constexpr float kWallHalf = 0.1f;   // walls are 20 cm thick
constexpr float kDoorHalf = 0.5f;   // doors 1 m wide, floor to ceiling
constexpr double kCornerRadiusM = 0.8;
constexpr double kCruiseMps = 0.45, kTurnMps = 0.15;
constexpr double kSlowZoneM = 1.5;   // speed blends to kTurnMps over this distance before/after a turn
constexpr double kAccelMps2 = 0.25;  // starting and stopping
constexpr double kHoldS = 0.5;       // standing still at the end
constexpr double kStepS = 1.0 / 600.0;
constexpr double kEyeHeightM = 1.45;
// Furniture keeps this far from the walked path (the Kinect sees nothing nearer than 0.4 m).
constexpr float kPathClearanceM = 0.7f;
constexpr double kMeshSpacingM = 0.05;  // 1,000 m^2 of floor alone: 5 cm keeps mesh_gt.ply near 1.5 M vertices

// A straight wall: along x at y = `at` (or along y at x = `at`) from `from`
// to `to`, with a door centred at each of `doors`.
struct WallLine {
  bool along_x;
  float at, from, to;
  std::vector<float> doors;
};

// The plan (metres; x east, y north). Rooms south y 0-4.6 and north 19.4-24,
// split at x = 10, 20, 30; corridors y 4.6-7.0 and 17.0-19.4 along x, and
// x 0-2.4, 18.8-21.2, 37.6-40 across; inner rooms between them split at
// x = 10.6 and 29.4. Ends reach into the wall they meet (no coplanar faces).
const std::vector<WallLine>& plan() {
  static const std::vector<WallLine> lines = {
      {true, 4.6f, 0.0f, 40.0f, {5, 15, 25, 35}},
      {true, 19.4f, 0.0f, 40.0f, {5, 15, 25, 35}},
      {true, 7.0f, 2.35f, 18.85f, {6.5f, 14.7f}},
      {true, 7.0f, 21.15f, 37.65f, {25.3f, 33.5f}},
      {true, 17.0f, 2.35f, 18.85f, {6.5f, 14.7f}},
      {true, 17.0f, 21.15f, 37.65f, {25.3f, 33.5f}},
      {false, 10.0f, 0.0f, 4.65f, {2.3f}},
      {false, 20.0f, 0.0f, 4.65f, {2.3f}},
      {false, 30.0f, 0.0f, 4.65f, {2.3f}},
      {false, 10.0f, 19.35f, 24.0f, {21.7f}},
      {false, 20.0f, 19.35f, 24.0f, {21.7f}},
      {false, 30.0f, 19.35f, 24.0f, {21.7f}},
      {false, 2.4f, 6.95f, 17.05f, {12}},
      {false, 10.6f, 6.95f, 17.05f, {12}},
      {false, 18.8f, 6.95f, 17.05f, {12}},
      {false, 21.2f, 6.95f, 17.05f, {12}},
      {false, 29.4f, 6.95f, 17.05f, {12}},
      {false, 37.6f, 6.95f, 17.05f, {12}},
  };
  return lines;
}

// The three laps, each from (3, 5.8) heading east back to it from the west,
// along corridor centre lines and through doors.
const std::vector<std::vector<Point2>>& laps() {
  static const std::vector<std::vector<Point2>> l = {
      // A: the south rooms end to end, back across the east inner rooms, the north-west rooms.
      {{3, 5.8}, {5, 5.8}, {5, 2.3}, {35, 2.3}, {35, 5.8}, {38.8, 5.8}, {38.8, 12}, {20, 12}, {20, 18.2}, {15, 18.2},
       {15, 21.7}, {5, 21.7}, {5, 18.2}, {1.2, 18.2}, {1.2, 5.8}, {3, 5.8}},
      // B: the south corridor, the east corridor, the north-east rooms, across the west inner rooms.
      {{3, 5.8}, {38.8, 5.8}, {38.8, 18.2}, {35, 18.2}, {35, 21.7}, {25, 21.7}, {25, 18.2}, {20, 18.2}, {20, 12},
       {1.2, 12}, {1.2, 5.8}, {3, 5.8}},
      // C: a serpentine through the four inner rooms, then the whole north corridor.
      {{3, 5.8}, {6.5, 5.8}, {6.5, 18.2}, {14.7, 18.2}, {14.7, 5.8}, {25.3, 5.8}, {25.3, 18.2}, {33.5, 18.2},
       {33.5, 5.8}, {38.8, 5.8}, {38.8, 18.2}, {1.2, 18.2}, {1.2, 5.8}, {3, 5.8}},
  };
  return l;
}

// Laps A, B, C, A, ... joined into one path.
RoundedPath pathOf(int n_laps) {
  std::vector<Point2> corners;
  for (int i = 0; i < n_laps; ++i) {
    const auto& lap = laps()[static_cast<size_t>(i) % laps().size()];
    corners.insert(corners.end(), lap.begin() + (i == 0 ? 0 : 1), lap.end());
  }
  return RoundedPath(corners, kCornerRadiusM);
}

double speed(const RoundedPath& path, double s, double t) {
  const double v = kCruiseMps + (kTurnMps - kCruiseMps) * path.turnWeight(s, kSlowZoneM);
  return std::min({v, kAccelMps2 * t + 0.02, std::sqrt(2.0 * kAccelMps2 * std::max(0.0, path.length() - s))});
}

int framesOfLaps(int n_laps) {
  const RoundedPath path = pathOf(n_laps);
  double t = 0, s = 0;
  while (s < path.length() - 1e-4 && t < 3000.0 * n_laps) {
    s += std::min(speed(path, s, t) * kStepS, path.length() - s);
    t += kStepS;
  }
  return static_cast<int>(std::ceil((t + kHoldS) * kFrameRateHz));
}

struct Footprint {
  float x0, y0, x1, y1;
  bool overlaps(const Footprint& o, float grow) const {
    return x0 - grow < o.x1 && o.x0 < x1 + grow && y0 - grow < o.y1 && o.y0 < y1 + grow;
  }
};
Footprint footprintOf(const Primitive& p) { return {p.bounds.lo.x, p.bounds.lo.y, p.bounds.hi.x, p.bounds.hi.y}; }

// Material of one wall piece: two colours, a checker or stripes, and noise of its own seed.
Material wallMaterial(Rng& rng, uint32_t seed) {
  auto uni = [&](double a, double b) { return static_cast<float>(a + (b - a) * rng.uniform()); };
  Material m;
  m.color_a = {uni(0.05, 0.45), uni(0.05, 0.45), uni(0.05, 0.45)};
  m.color_b = {uni(0.6, 1.0), uni(0.6, 1.0), uni(0.6, 1.0)};
  if (rng.uniform() < 0.5) {
    m.checker_period = uni(0.3, 1.0);
    m.checker_weight = uni(0.15, 0.35);
  } else {
    m.stripe_period = uni(0.05, 0.3);
    const float angle = uni(0.0, 3.1);
    m.stripe_cos = std::cos(angle);
    m.stripe_sin = std::sin(angle);
    m.stripe_weight = uni(0.2, 0.35);
  }
  m.noise_weight = uni(0.6, 0.8);
  m.seed = seed;
  return m;
}

class BuildingModel {
 public:
  BuildingModel() : path_samples_(pathOf(static_cast<int>(laps().size())).samples(0.1)) {
    model_.shell = shell({0, 0, 0}, {kSizeX, kSizeY, kHeight}, kWallWarm, kWallCool, kWallCool, kWallWarm, kFloor, kCeiling);
    materials_ = palette();
    addWalls();
    const size_t walls = model_.primitives.size();
    for (size_t i = 0; i < walls; ++i) furnishAlong(model_.primitives[i]);
    furnishShell();
    addIslands();
  }
  SceneModel model() const { return model_; }
  std::vector<Material> materials() const { return materials_; }

 private:
  void addWalls() {
    Rng rng(0xB11D1ull);
    for (const WallLine& w : plan()) {
      float start = w.from;
      auto piece = [&](float a, float b) {
        if (b - a < 1e-3f) return;
        const int mat = static_cast<int>(materials_.size());
        materials_.push_back(wallMaterial(rng, 1000u + static_cast<uint32_t>(mat)));
        const float mid = 0.5f * (a + b), half = 0.5f * (b - a);
        const V3 centre = w.along_x ? V3{mid, w.at, 0.5f * kHeight} : V3{w.at, mid, 0.5f * kHeight};
        const V3 extent = w.along_x ? V3{half, kWallHalf, 0.5f * kHeight} : V3{kWallHalf, half, 0.5f * kHeight};
        model_.primitives.push_back(makeBox(centre, extent, 0.0f, mat));
        walls_.push_back(footprintOf(model_.primitives.back()));
      };
      for (float d : w.doors) {
        piece(start, d - kDoorHalf);
        start = d + kDoorHalf;
      }
      piece(start, w.to);
    }
  }

  bool nearPath(const Footprint& f) const {
    for (const Point2& p : path_samples_) {
      const float dx = std::max({f.x0 - static_cast<float>(p.x), static_cast<float>(p.x) - f.x1, 0.0f});
      const float dy = std::max({f.y0 - static_cast<float>(p.y), static_cast<float>(p.y) - f.y1, 0.0f});
      if (dx * dx + dy * dy < kPathClearanceM * kPathClearanceM) return true;
    }
    return false;
  }

  // Whether a group of primitives fits: clear of the path (unless flat on a
  // wall), of the walls (except the one it stands against) and of the furniture.
  bool fits(const std::vector<Primitive>& group, bool on_wall) const {
    Footprint f = footprintOf(group.front());
    for (const auto& p : group) {
      const Footprint g = footprintOf(p);
      f = {std::min(f.x0, g.x0), std::min(f.y0, g.y0), std::max(f.x1, g.x1), std::max(f.y1, g.y1)};
    }
    if (f.x0 < 0.05f || f.y0 < 0.05f || f.x1 > kSizeX - 0.05f || f.y1 > kSizeY - 0.05f) return false;
    if (!on_wall && nearPath(f)) return false;
    // Against a wall the footprint touches it: shrink by 1 cm for the test.
    const Footprint inner{f.x0 + 0.01f, f.y0 + 0.01f, f.x1 - 0.01f, f.y1 - 0.01f};
    for (const auto& w : walls_)
      if (inner.overlaps(w, on_wall ? 0.0f : 0.3f)) return false;
    for (const auto& o : furniture_)
      if (inner.overlaps(o, 0.15f)) return false;
    return true;
  }

  void place(const std::vector<Primitive>& group, bool on_wall) {
    if (!fits(group, on_wall)) return;
    Footprint f = footprintOf(group.front());
    for (const auto& p : group) {
      const Footprint g = footprintOf(p);
      f = {std::min(f.x0, g.x0), std::min(f.y0, g.y0), std::max(f.x1, g.x1), std::max(f.y1, g.y1)};
      model_.primitives.push_back(p);
    }
    furniture_.push_back(f);
  }

  int objectMaterial() {
    static const int mats[] = {kRed, kGreen, kBlue, kYellow, kMetal, kPurple, kPoster, kWood};
    return mats[rng_.next() % 8];
  }
  float uni(double a, double b) { return static_cast<float>(a + (b - a) * rng_.uniform()); }

  // Objects along one face of a wall: (ox, oy) a point on the face, (tx, ty)
  // along it, (nx, ny) its outward normal, `length` its extent.
  void furnishFace(float ox, float oy, float tx, float ty, float nx, float ny, float length) {
    float a = uni(0.2, 1.0);
    while (a < length - 0.3f) {
      const double kind = rng_.uniform();
      float width = 0.0f;
      auto at = [&](float along, float out) { return V3{ox + tx * along + nx * out, oy + ty * along + ny * out, 0.0f}; };
      auto halfXY = [&](float along_half, float out_half, float z_half) {
        return std::abs(tx) > 0.5f ? V3{along_half, out_half, z_half} : V3{out_half, along_half, z_half};
      };
      if (kind < 0.3) {  // cabinet, sometimes with a ball on top
        const float d = uni(0.25, 0.45), w = uni(0.5, 1.2), h = uni(0.6, 1.9);
        if (a + w > length) break;  // never past the wall's end (into a door)
        V3 c = at(a + 0.5f * w, 0.5f * d);
        c.z = 0.5f * h;
        std::vector<Primitive> g = {makeBox(c, halfXY(0.5f * w, 0.5f * d, 0.5f * h), 0.0f, objectMaterial())};
        if (h < 1.2f && rng_.uniform() < 0.5) {
          const float r = uni(0.08, 0.15);
          g.push_back(makeSphere({c.x, c.y, h + r}, r, objectMaterial()));
        }
        place(g, false);
        width = w;
      } else if (kind < 0.5) {  // bin or drum
        const float r = uni(0.12, 0.25), h = uni(0.4, 1.1);
        if (a + 2 * r > length) break;
        place({makeCylinder(at(a + r, r + 0.05f), r, h, objectMaterial())}, false);
        width = 2 * r;
      } else {  // picture or board on the wall
        const float w = uni(0.5, 1.4), h = uni(0.4, 0.9), z = uni(1.1, 1.9);
        if (a + w > length) break;
        V3 c = at(a + 0.5f * w, 0.015f);
        c.z = z;
        place({makeBox(c, halfXY(0.5f * w, 0.015f, 0.5f * h), 0.0f, objectMaterial())}, true);
        width = w;
      }
      a += width + uni(0.4, 1.5);
    }
  }

  void furnishAlong(const Primitive& wall) {
    const bool along_x = wall.half.x > wall.half.y;
    if (along_x) {
      const float len = 2 * wall.half.x, x0 = wall.center.x - wall.half.x;
      furnishFace(x0, wall.center.y + kWallHalf, 1, 0, 0, 1, len);
      furnishFace(x0, wall.center.y - kWallHalf, 1, 0, 0, -1, len);
    } else {
      const float len = 2 * wall.half.y, y0 = wall.center.y - wall.half.y;
      furnishFace(wall.center.x + kWallHalf, y0, 0, 1, 1, 0, len);
      furnishFace(wall.center.x - kWallHalf, y0, 0, 1, -1, 0, len);
    }
  }

  void furnishShell() {
    furnishFace(0, 0, 1, 0, 0, 1, kSizeX);
    furnishFace(0, kSizeY, 1, 0, 0, -1, kSizeX);
    furnishFace(0, 0, 0, 1, 1, 0, kSizeY);
    furnishFace(kSizeX, 0, 0, 1, -1, 0, kSizeY);
  }

  // Tables, drums, boxes and balls standing free wherever the path leaves room.
  void addIslands() {
    for (int i = 0; i < 400; ++i) {
      const float x = uni(0.5, kSizeX - 0.5), y = uni(0.5, kSizeY - 0.5), yaw = uni(0.0, 1.5);
      const double kind = rng_.uniform();
      std::vector<Primitive> g;
      if (kind < 0.35) {
        const float hx = uni(0.4, 0.8), hy = uni(0.3, 0.5), h = uni(0.7, 0.8);
        addTable(&g, x, y, hx, hy, h, yaw, kWood);
        g.push_back(makeBox({x + 0.2f * hx, y, h + 0.08f}, {0.12f, 0.09f, 0.08f}, yaw + 0.4f, objectMaterial()));
      } else if (kind < 0.6) {
        g.push_back(makeCylinder({x, y, 0}, uni(0.15, 0.3), uni(0.5, 1.3), objectMaterial()));
      } else if (kind < 0.85) {
        const float s = uni(0.2, 0.45);
        g.push_back(makeBox({x, y, s}, {s, uni(0.2, 0.45), s}, yaw, objectMaterial()));
        if (rng_.uniform() < 0.5) g.push_back(makeSphere({x, y, 2 * s + 0.15f}, 0.15f, objectMaterial()));
      } else {
        const float r = uni(0.2, 0.35);
        g.push_back(makeSphere({x, y, r}, r, objectMaterial()));
      }
      place(g, false);
    }
  }

  SceneModel model_;
  std::vector<Material> materials_;
  std::vector<Point2> path_samples_;
  std::vector<Footprint> walls_, furniture_;
  Rng rng_{0xB11D2ull};  // the geometry is fixed; seeds change only motion and noise
};

// `n_laps` laps (A, B, C, A, ...), or as many more as `frames` needs; the
// walker stops at the end of the last lap.
Trajectory buildingTrajectory(int frames, uint64_t seed, int n_laps) {
  while (framesOfLaps(n_laps) < frames) ++n_laps;
  const RoundedPath path = pathOf(n_laps);
  Rng rng(mixSeed(seed, 0xB11D3ull));
  double ph[5];
  for (double& x : ph) x = 2 * kPi * rng.uniform();
  const Shake shake(seed, 60.0, 0.002, 0.003);  // harmonics of 1/60 Hz: the walk is not periodic
  Trajectory out;
  out.reserve(static_cast<size_t>(frames));
  double t = 0, s = 0;
  int next = 0;
  while (next < frames) {
    if (t + 1e-9 >= next / kFrameRateHz) {
      const double tf = next / kFrameRateHz;
      const RoundedPath::State st = path.at(s);
      const double look = 1.0 - path.turnWeight(s, kSlowZoneM);  // no looking around in a turn
      const double yaw = st.heading + look * 20.0 * kDeg * std::sin(2 * kPi * tf / 9.0 + ph[0]);
      const double pitch = -12.0 * kDeg + 4.0 * kDeg * std::sin(2 * kPi * tf / 7.0 + ph[1]);
      const double roll = 1.5 * kDeg * std::sin(2 * kPi * tf / 5.0 + ph[2]);
      const double z = kEyeHeightM + 0.005 * std::sin(2 * kPi * 1.8 * tf + ph[3]);
      out.push_back({tf, shaken(shake, tf, Eigen::Vector3d(st.x, st.y, z), yaw, pitch, roll)});
      ++next;
    }
    s += std::min(speed(path, s, t) * kStepS, path.length() - s);
    t += kStepS;
  }
  return out;
}

}  // namespace

std::unique_ptr<AnalyticScene> makeBuildingScene() {
  const BuildingModel b;
  return std::make_unique<AnalyticScene>("building", b.model(), b.materials(), kMeshSpacingM, framesOfLaps,
                                         buildingTrajectory);
}

}  // namespace rekon::synth
