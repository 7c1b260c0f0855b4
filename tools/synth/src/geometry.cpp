#include "geometry.hpp"

#include <limits>

namespace rekon::synth {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// World point -> box-local frame (yaw about z only).
inline V3 toLocal(const Primitive& p, V3 w) {
  const V3 r = w - p.center;
  return {p.cos_yaw * r.x + p.sin_yaw * r.y, -p.sin_yaw * r.x + p.cos_yaw * r.y, r.z};
}
inline V3 dirToLocal(const Primitive& p, V3 d) {
  return {p.cos_yaw * d.x + p.sin_yaw * d.y, -p.sin_yaw * d.x + p.cos_yaw * d.y, d.z};
}
inline V3 dirToWorld(const Primitive& p, V3 d) {
  return {p.cos_yaw * d.x - p.sin_yaw * d.y, p.sin_yaw * d.x + p.cos_yaw * d.y, d.z};
}

}  // namespace

Primitive makeBox(V3 center, V3 half, float yaw_rad, int material) {
  Primitive p;
  p.shape = Shape::Box;
  p.material = material;
  p.center = center;
  p.half = half;
  p.cos_yaw = std::cos(yaw_rad);
  p.sin_yaw = std::sin(yaw_rad);
  const float ex = std::abs(p.cos_yaw) * half.x + std::abs(p.sin_yaw) * half.y;
  const float ey = std::abs(p.sin_yaw) * half.x + std::abs(p.cos_yaw) * half.y;
  p.bounds = {{center.x - ex, center.y - ey, center.z - half.z}, {center.x + ex, center.y + ey, center.z + half.z}};
  return p;
}

Primitive makeCylinder(V3 base_center, float radius, float height, int material) {
  Primitive p;
  p.shape = Shape::Cylinder;
  p.material = material;
  p.center = {base_center.x, base_center.y, base_center.z + 0.5f * height};
  p.half = {radius, radius, 0.5f * height};
  p.bounds = {{p.center.x - radius, p.center.y - radius, base_center.z},
              {p.center.x + radius, p.center.y + radius, base_center.z + height}};
  return p;
}

Primitive makeSphere(V3 center, float radius, int material) {
  Primitive p;
  p.shape = Shape::Sphere;
  p.material = material;
  p.center = center;
  p.half = {radius, radius, radius};
  p.bounds = {center - V3{radius, radius, radius}, center + V3{radius, radius, radius}};
  return p;
}

float intersect(const Primitive& p, V3 o, V3 d, float t_min, float t_max, int* part) {
  switch (p.shape) {
    case Shape::Box: {
      const V3 lo = toLocal(p, o), ld = dirToLocal(p, d);
      float t0 = t_min, t1 = t_max;
      int entry = -1;
      const float oc[3] = {lo.x, lo.y, lo.z}, dc[3] = {ld.x, ld.y, ld.z}, hc[3] = {p.half.x, p.half.y, p.half.z};
      for (int a = 0; a < 3; ++a) {
        if (std::abs(dc[a]) < 1e-12f) {
          if (oc[a] < -hc[a] || oc[a] > hc[a]) return kInf;
          continue;
        }
        const float inv = 1.0f / dc[a];
        float tn = (-hc[a] - oc[a]) * inv, tf = (hc[a] - oc[a]) * inv;
        int face = 2 * a;  // entering through the -a face when the ray runs along +a
        if (tn > tf) {
          std::swap(tn, tf);
          face = 2 * a + 1;
        }
        if (tn > t0) {
          t0 = tn;
          entry = face;
        }
        t1 = std::min(t1, tf);
        if (t0 > t1) return kInf;
      }
      if (entry < 0) return kInf;  // origin inside the box: not a visible outer face
      *part = entry;
      return t0;
    }
    case Shape::Cylinder: {
      const float r = p.half.x;
      const float ox = o.x - p.center.x, oy = o.y - p.center.y;
      const float z0 = p.center.z - p.half.z, z1 = p.center.z + p.half.z;
      float best = kInf;
      const float a = d.x * d.x + d.y * d.y;
      if (a > 1e-12f) {
        const float b = ox * d.x + oy * d.y;
        const float c = ox * ox + oy * oy - r * r;
        const float disc = b * b - a * c;
        if (disc < 0) return kInf;  // the infinite cylinder is missed, so are the caps
        const float t = (-b - std::sqrt(disc)) / a;
        if (t > t_min && t < t_max) {
          const float z = o.z + t * d.z;
          if (z >= z0 && z <= z1) {
            *part = 0;
            return t;
          }
        }
      }
      if (d.z != 0.0f) {
        const bool from_above = d.z < 0;
        const float zc = from_above ? z1 : z0;
        const float t = (zc - o.z) / d.z;
        if (t > t_min && t < t_max) {
          const float x = ox + t * d.x, y = oy + t * d.y;
          if (x * x + y * y <= r * r) {
            *part = from_above ? 2 : 1;
            best = t;
          }
        }
      }
      return best;
    }
    case Shape::Sphere: {
      const V3 oc = o - p.center;
      const float a = dot(d, d), b = dot(oc, d), c = dot(oc, oc) - p.half.x * p.half.x;
      const float disc = b * b - a * c;
      if (disc < 0) return kInf;
      const float t = (-b - std::sqrt(disc)) / a;
      if (t > t_min && t < t_max) {
        *part = 0;
        return t;
      }
      return kInf;
    }
  }
  return kInf;
}

float intersectShell(const Shell& s, V3 o, V3 d, int* face) {
  float best = kInf;
  const float oc[3] = {o.x, o.y, o.z}, dc[3] = {d.x, d.y, d.z};
  const float lo[3] = {s.box.lo.x, s.box.lo.y, s.box.lo.z}, hi[3] = {s.box.hi.x, s.box.hi.y, s.box.hi.z};
  for (int a = 0; a < 3; ++a) {
    if (dc[a] > 0) {
      const float t = (hi[a] - oc[a]) / dc[a];
      if (t < best) {
        best = t;
        *face = 2 * a + 1;
      }
    } else if (dc[a] < 0) {
      const float t = (lo[a] - oc[a]) / dc[a];
      if (t < best) {
        best = t;
        *face = 2 * a;
      }
    }
  }
  return best;
}

SurfacePoint surfaceOf(const Primitive& p, V3 point, int part) {
  SurfacePoint s;
  s.position = point;
  s.material = p.material;
  s.part = part;
  switch (p.shape) {
    case Shape::Box: {
      const V3 l = toLocal(p, point);
      const int axis = part / 2;
      const float sign = (part % 2) ? 1.0f : -1.0f;
      V3 n_local{0, 0, 0};
      if (axis == 0) n_local.x = sign;
      if (axis == 1) n_local.y = sign;
      if (axis == 2) n_local.z = sign;
      s.normal = dirToWorld(p, n_local);
      // Vertical faces use height as v so textures line up across stacked boxes;
      // an offset per face keeps opposite faces from looking identical.
      const float offset = 0.37f * static_cast<float>(part);
      if (axis == 0) {
        s.u = l.y + offset;
        s.v = point.z;
      } else if (axis == 1) {
        s.u = l.x + offset;
        s.v = point.z;
      } else {
        s.u = l.x + offset;
        s.v = l.y;
      }
      break;
    }
    case Shape::Cylinder: {
      const float dx = point.x - p.center.x, dy = point.y - p.center.y;
      if (part == 0) {
        const float inv = 1.0f / std::sqrt(dx * dx + dy * dy);
        s.normal = {dx * inv, dy * inv, 0};
        s.u = std::atan2(dy, dx) * p.half.x;  // arc length
        s.v = point.z;
      } else {
        s.normal = {0, 0, part == 2 ? 1.0f : -1.0f};
        s.u = dx;
        s.v = dy;
      }
      break;
    }
    case Shape::Sphere: {
      const V3 n = normalized(point - p.center);
      s.normal = n;
      const float r = p.half.x;
      s.u = std::atan2(n.y, n.x) * r;
      s.v = std::asin(std::clamp(n.z, -1.0f, 1.0f)) * r;
      break;
    }
  }
  return s;
}

SurfacePoint surfaceOfShell(const Shell& sh, V3 point, int face) {
  SurfacePoint s;
  s.position = point;
  s.material = sh.material[face];
  s.part = face;
  const int axis = face / 2;
  const float sign = (face % 2) ? -1.0f : 1.0f;  // normals point into the room
  s.normal = {axis == 0 ? sign : 0.0f, axis == 1 ? sign : 0.0f, axis == 2 ? sign : 0.0f};
  if (axis == 0) {
    s.u = point.y;
    s.v = point.z;
  } else if (axis == 1) {
    s.u = point.x;
    s.v = point.z;
  } else {
    s.u = point.x;
    s.v = point.y;
  }
  return s;
}

bool inside(const Primitive& p, V3 point, float margin) {
  switch (p.shape) {
    case Shape::Box: {
      const V3 l = toLocal(p, point);
      return std::abs(l.x) <= p.half.x + margin && std::abs(l.y) <= p.half.y + margin && std::abs(l.z) <= p.half.z + margin;
    }
    case Shape::Cylinder: {
      const float dx = point.x - p.center.x, dy = point.y - p.center.y;
      const float r = p.half.x + margin;
      return dx * dx + dy * dy <= r * r && std::abs(point.z - p.center.z) <= p.half.z + margin;
    }
    case Shape::Sphere: {
      const V3 r = point - p.center;
      const float rad = p.half.x + margin;
      return dot(r, r) <= rad * rad;
    }
  }
  return false;
}

}  // namespace rekon::synth
