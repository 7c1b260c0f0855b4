// The exact scene surface as a colored triangle mesh: each face of the model
// is a parametric patch sampled on a grid; grid cells hidden inside another
// solid (the floor under a box, a box face against a wall) are left out.
#include <cmath>
#include <functional>
#include <numbers>

#include "analytic_scene.hpp"

namespace rekon::synth {
namespace {

// Cells whose centre is this close to the inside of another solid are hidden.
constexpr float kHiddenMarginM = 1e-3f;
// Largest distance between a curved surface and its chords.
constexpr float kMaxSagittaM = 2e-4f;

// Segments around a circle of radius r: at most `spacing` long and at most kMaxSagittaM off the circle.
int segmentsAround(float r, float spacing) {
  const float pi = std::numbers::pi_v<float>;
  const int by_spacing = static_cast<int>(std::ceil(2 * pi * r / spacing));
  const int by_sagitta = r > kMaxSagittaM ? static_cast<int>(std::ceil(pi / std::acos(1.0f - kMaxSagittaM / r))) : 3;
  return std::max({12, by_spacing, by_sagitta});
}

class MeshBuilder {
 public:
  MeshBuilder(const SceneModel& model, const std::vector<Material>& materials, double spacing)
      : model_(model), materials_(materials), spacing_(static_cast<float>(spacing)) {}

  // A patch P(a, b), a, b in [0, 1], with na x nb cells; `surface` gives the
  // surface point (with normal and texture coordinates) at a patch point.
  void patch(int owner, int na, int nb, const std::function<V3(float, float)>& position,
             const std::function<SurfacePoint(V3)>& surface) {
    const int base = static_cast<int>(mesh_.vertices.size());
    for (int j = 0; j <= nb; ++j) {
      for (int i = 0; i <= na; ++i) {
        const V3 p = position(static_cast<float>(i) / na, static_cast<float>(j) / nb);
        const SurfacePoint s = surface(p);
        const V3 c = shade(materials_[static_cast<size_t>(s.material)], s, spacing_);
        mesh_.vertices.emplace_back(p.x, p.y, p.z);
        mesh_.colors.push_back({toByte(c.x), toByte(c.y), toByte(c.z)});
      }
    }
    auto index = [&](int i, int j) { return base + j * (na + 1) + i; };
    for (int j = 0; j < nb; ++j) {
      for (int i = 0; i < na; ++i) {
        const V3 centre = position((i + 0.5f) / na, (j + 0.5f) / nb);
        if (hidden(owner, centre)) continue;
        const V3 outward = surface(centre).normal;
        addTriangle(index(i, j), index(i + 1, j), index(i + 1, j + 1), outward);
        addTriangle(index(i, j), index(i + 1, j + 1), index(i, j + 1), outward);
      }
    }
  }

  int cells(float length) const { return std::max(1, static_cast<int>(std::ceil(length / spacing_))); }

  // Drops the vertices no triangle uses (those of hidden cells).
  Mesh finish() {
    std::vector<int> remap(mesh_.vertices.size(), -1);
    Mesh out;
    for (auto& t : mesh_.triangles) {
      for (int k = 0; k < 3; ++k) {
        int& r = remap[static_cast<size_t>(t[k])];
        if (r < 0) {
          r = static_cast<int>(out.vertices.size());
          out.vertices.push_back(mesh_.vertices[static_cast<size_t>(t[k])]);
          out.colors.push_back(mesh_.colors[static_cast<size_t>(t[k])]);
        }
        t[k] = r;
      }
    }
    out.triangles = std::move(mesh_.triangles);
    return out;
  }

 private:
  static uint8_t toByte(float v) { return static_cast<uint8_t>(std::lround(std::clamp(v, 0.0f, 1.0f) * 255.0f)); }

  bool hidden(int owner, V3 p) const {
    if (owner != kShellId) {
      const Aabb& b = model_.shell.box;
      const float m = kHiddenMarginM;
      if (p.x < b.lo.x + m || p.x > b.hi.x - m || p.y < b.lo.y + m || p.y > b.hi.y - m || p.z < b.lo.z + m ||
          p.z > b.hi.z - m) {
        return true;
      }
    }
    for (size_t i = 0; i < model_.primitives.size(); ++i) {
      if (static_cast<int>(i) == owner) continue;
      const Primitive& q = model_.primitives[i];
      const Aabb& b = q.bounds;
      if (p.x < b.lo.x - kHiddenMarginM || p.x > b.hi.x + kHiddenMarginM || p.y < b.lo.y - kHiddenMarginM ||
          p.y > b.hi.y + kHiddenMarginM || p.z < b.lo.z - kHiddenMarginM || p.z > b.hi.z + kHiddenMarginM) {
        continue;
      }
      if (inside(q, p, kHiddenMarginM)) return true;
    }
    return false;
  }

  void addTriangle(int a, int b, int c, V3 outward) {
    const auto& va = mesh_.vertices[static_cast<size_t>(a)];
    const Eigen::Vector3f n = (mesh_.vertices[static_cast<size_t>(b)] - va).cross(mesh_.vertices[static_cast<size_t>(c)] - va);
    if (n.squaredNorm() < 1e-16f) return;  // collapsed cell at a pole or a cap centre
    if (n.dot(Eigen::Vector3f(outward.x, outward.y, outward.z)) < 0) std::swap(b, c);
    mesh_.triangles.emplace_back(a, b, c);
  }

  const SceneModel& model_;
  const std::vector<Material>& materials_;
  float spacing_;
  Mesh mesh_;
};

}  // namespace

Mesh triangulate(const SceneModel& model, const std::vector<Material>& materials, double spacing_m) {
  MeshBuilder mb(model, materials, spacing_m);
  const Shell& shell = model.shell;
  const V3 lo = shell.box.lo, hi = shell.box.hi;
  const float ext[3] = {hi.x - lo.x, hi.y - lo.y, hi.z - lo.z};
  for (int face = 0; face < 6; ++face) {
    const int axis = face / 2;
    const int ua = (axis + 1) % 3, va = (axis + 2) % 3;
    auto position = [&, face, axis, ua, va](float a, float b) {
      float p[3];
      p[axis] = (face % 2) ? (axis == 0 ? hi.x : axis == 1 ? hi.y : hi.z) : (axis == 0 ? lo.x : axis == 1 ? lo.y : lo.z);
      const float los[3] = {lo.x, lo.y, lo.z};
      p[ua] = los[ua] + a * ext[ua];
      p[va] = los[va] + b * ext[va];
      return V3{p[0], p[1], p[2]};
    };
    mb.patch(kShellId, mb.cells(ext[ua]), mb.cells(ext[va]), position,
             [&, face](V3 p) { return surfaceOfShell(shell, p, face); });
  }

  for (size_t idx = 0; idx < model.primitives.size(); ++idx) {
    const Primitive& q = model.primitives[idx];
    const int owner = static_cast<int>(idx);
    switch (q.shape) {
      case Shape::Box: {
        const V3 ax{q.cos_yaw, q.sin_yaw, 0}, ay{-q.sin_yaw, q.cos_yaw, 0}, az{0, 0, 1};
        const V3 axes[3] = {ax, ay, az};
        const float half[3] = {q.half.x, q.half.y, q.half.z};
        for (int face = 0; face < 6; ++face) {
          const int axis = face / 2, ua = (axis + 1) % 3, va = (axis + 2) % 3;
          const float sign = (face % 2) ? 1.0f : -1.0f;
          const V3 centre = q.center + axes[axis] * (sign * half[axis]);
          const V3 corner = centre - axes[ua] * half[ua] - axes[va] * half[va];
          const V3 eu = axes[ua] * (2 * half[ua]), ev = axes[va] * (2 * half[va]);
          mb.patch(owner, mb.cells(2 * half[ua]), mb.cells(2 * half[va]),
                   [=](float a, float b) { return corner + eu * a + ev * b; },
                   [&q, face](V3 p) { return surfaceOf(q, p, face); });
        }
        break;
      }
      case Shape::Cylinder: {
        const float r = q.half.x, z0 = q.center.z - q.half.z, z1 = q.center.z + q.half.z;
        const float pi = std::numbers::pi_v<float>;
        const int around = segmentsAround(r, static_cast<float>(spacing_m));
        mb.patch(owner, around, mb.cells(z1 - z0),
                 [=](float a, float b) {
                   const float th = -pi + 2 * pi * a;
                   return V3{q.center.x + r * std::cos(th), q.center.y + r * std::sin(th), z0 + b * (z1 - z0)};
                 },
                 [&q](V3 p) { return surfaceOf(q, p, 0); });
        for (int part = 1; part <= 2; ++part) {
          const float z = part == 2 ? z1 : z0;
          mb.patch(owner, mb.cells(r), around,
                   [=](float a, float b) {
                     const float th = -pi + 2 * pi * b;
                     return V3{q.center.x + a * r * std::cos(th), q.center.y + a * r * std::sin(th), z};
                   },
                   [&q, part](V3 p) { return surfaceOf(q, p, part); });
        }
        break;
      }
      case Shape::Sphere: {
        const float r = q.half.x, pi = std::numbers::pi_v<float>;
        const int around = segmentsAround(r, static_cast<float>(spacing_m)), along = std::max(6, around / 2);
        mb.patch(owner, around, along,
                 [=](float a, float b) {
                   const float th = -pi + 2 * pi * a, ph = -0.5f * pi + pi * b;
                   return V3{q.center.x + r * std::cos(ph) * std::cos(th), q.center.y + r * std::cos(ph) * std::sin(th),
                             q.center.z + r * std::sin(ph)};
                 },
                 [&q](V3 p) { return surfaceOf(q, p, 0); });
        break;
      }
    }
  }
  return mb.finish();
}

}  // namespace rekon::synth
