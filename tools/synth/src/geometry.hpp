#pragma once
// The analytic scene: one room-like shell seen from inside (walls, floor,
// ceiling) plus solid primitives (yawed boxes, upright cylinders, spheres),
// with float ray intersection written once for the ray caster and the
// ground-truth mesh. World frame: z up, metres.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace rekon::synth {

struct V3 {
  float x = 0, y = 0, z = 0;
};
inline V3 operator+(V3 a, V3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline V3 operator-(V3 a, V3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline V3 operator*(V3 a, float s) { return {a.x * s, a.y * s, a.z * s}; }
inline float dot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline V3 cross(V3 a, V3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
inline float norm(V3 a) { return std::sqrt(dot(a, a)); }
inline V3 normalized(V3 a) { return a * (1.0f / norm(a)); }

struct Aabb {
  V3 lo, hi;
};

enum class Shape : uint8_t { Box, Cylinder, Sphere };

// A solid. Box: centre, yaw about z, half extents. Cylinder: upright, axis
// through centre.xy, from centre.z - half.z to centre.z + half.z, radius half.x.
// Sphere: centre, radius half.x.
struct Primitive {
  Shape shape = Shape::Box;
  int material = 0;
  V3 center;
  V3 half;
  float cos_yaw = 1, sin_yaw = 0;
  Aabb bounds;
};

// The surface a ray hit: `part` tells which face (box faces 0..5 as
// -x,+x,-y,+y,-z,+z in the local frame; cylinder 0 side, 1 bottom, 2 top).
struct SurfacePoint {
  V3 position;
  V3 normal;
  float u = 0, v = 0;  // texture coordinates in metres along the surface
  int material = 0;
  int part = 0;
};

// Sentinel for "the shell" in hit records.
constexpr int kShellId = -1;

struct Shell {
  Aabb box;            // the interior
  int material[6]{};   // per face: -x,+x,-y,+y,floor(-z),ceiling(+z)
};

struct SceneModel {
  Shell shell;
  std::vector<Primitive> primitives;
};

Primitive makeBox(V3 center, V3 half, float yaw_rad, int material);
Primitive makeCylinder(V3 base_center, float radius, float height, int material);
Primitive makeSphere(V3 center, float radius, int material);

// Nearest hit of the ray o + t d (t > t_min, t < t_max) with the primitive;
// returns t or +inf; `part` receives the face.
float intersect(const Primitive& p, V3 o, V3 d, float t_min, float t_max, int* part);
// Exit distance of a ray starting inside the shell, and the face it leaves through.
float intersectShell(const Shell& s, V3 o, V3 d, int* face);

// Position, normal and texture coordinates of the hit at `point` on `part`.
SurfacePoint surfaceOf(const Primitive& p, V3 point, int part);
SurfacePoint surfaceOfShell(const Shell& s, V3 point, int face);

// True when `point` lies inside the solid (grown by `margin`).
bool inside(const Primitive& p, V3 point, float margin);

}  // namespace rekon::synth
