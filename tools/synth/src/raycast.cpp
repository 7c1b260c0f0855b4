#include "raycast.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <thread>

namespace rekon::synth {
namespace {

constexpr float kNearM = 1e-3f;
constexpr int kRowsPerChunk = 8;
// Shortest incidence cosine used for the texture footprint (keeps grazing
// surfaces from blurring to a flat color).
constexpr float kMinFootprintCos = 0.2f;

// Screen rectangle (inclusive) where a primitive can appear; empty when behind.
struct ScreenRect {
  int index;
  int x0, x1, y0, y1;
  float near_m;  // distance from the camera to the primitive's bounding box: no hit is nearer
};

struct Camera {
  float r[3][3];  // camera-to-world rotation
  V3 origin;
  float fx, fy, cx, cy;

  V3 rayDirection(float px, float py) const {
    const float x = (px - cx) / fx, y = (py - cy) / fy;
    return {r[0][0] * x + r[0][1] * y + r[0][2], r[1][0] * x + r[1][1] * y + r[1][2], r[2][0] * x + r[2][1] * y + r[2][2]};
  }
  V3 toCamera(V3 w) const {
    const V3 d = w - origin;
    return {r[0][0] * d.x + r[1][0] * d.y + r[2][0] * d.z, r[0][1] * d.x + r[1][1] * d.y + r[2][1] * d.z,
            r[0][2] * d.x + r[1][2] * d.y + r[2][2] * d.z};
  }
};

bool screenRect(const Camera& cam, const Aabb& b, int width, int height, ScreenRect* out) {
  float u0 = std::numeric_limits<float>::max(), u1 = -u0, v0 = u0, v1 = -u0;
  int behind = 0;
  for (int i = 0; i < 8; ++i) {
    const V3 w{(i & 1) ? b.hi.x : b.lo.x, (i & 2) ? b.hi.y : b.lo.y, (i & 4) ? b.hi.z : b.lo.z};
    const V3 c = cam.toCamera(w);
    if (c.z < kNearM) {
      ++behind;
      continue;
    }
    const float u = cam.fx * c.x / c.z + cam.cx, v = cam.fy * c.y / c.z + cam.cy;
    u0 = std::min(u0, u);
    u1 = std::max(u1, u);
    v0 = std::min(v0, v);
    v1 = std::max(v1, v);
  }
  if (behind == 8) return false;
  if (behind > 0) {  // straddles the camera plane: anywhere on screen
    *out = {0, 0, width - 1, 0, height - 1, 0.0f};
    return true;
  }
  out->x0 = std::max(0, static_cast<int>(std::floor(u0)) - 1);
  out->x1 = std::min(width - 1, static_cast<int>(std::ceil(u1)) + 1);
  out->y0 = std::max(0, static_cast<int>(std::floor(v0)) - 1);
  out->y1 = std::min(height - 1, static_cast<int>(std::ceil(v1)) + 1);
  return out->x0 <= out->x1 && out->y0 <= out->y1;
}

struct Hit {
  float t;
  int id;  // primitive index, or kShellId
  int part;
};

// `cands` are sorted by near_m: once a candidate's box lies farther than the
// nearest hit so far, so do the rest (a building's walls hide most of what
// is in the view). The nearest hit wins, ties going to the shell and then to
// the lowest primitive index, whatever order the candidates come in.
inline Hit castRay(const SceneModel& scene, const ScreenRect* cands, int n_cands, int px, V3 o, V3 d) {
  Hit h{0, kShellId, 0};
  h.t = intersectShell(scene.shell, o, d, &h.part);
  const float len = norm(d);
  for (int c = 0; c < n_cands; ++c) {
    const ScreenRect& r = cands[c];
    // Distance along the ray is t |d|; the margin covers float rounding of both sides.
    if (r.near_m > h.t * len * (1.0f + 1e-5f) + 1e-5f) break;
    if (px < r.x0 || px > r.x1) continue;
    int part = 0;
    const float t = intersect(scene.primitives[static_cast<size_t>(r.index)], o, d, kNearM,
                              std::nextafter(h.t, std::numeric_limits<float>::infinity()), &part);
    if (t < h.t || (t == h.t && h.id != kShellId && r.index < h.id)) h = {t, r.index, part};
  }
  return h;
}

float distanceToBox(V3 p, const Aabb& b) {
  const float dx = std::max({b.lo.x - p.x, p.x - b.hi.x, 0.0f});
  const float dy = std::max({b.lo.y - p.y, p.y - b.hi.y, 0.0f});
  const float dz = std::max({b.lo.z - p.z, p.z - b.hi.z, 0.0f});
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

inline SurfacePoint surfaceAt(const SceneModel& scene, const Hit& h, V3 o, V3 d) {
  const V3 p = o + d * h.t;
  return h.id == kShellId ? surfaceOfShell(scene.shell, p, h.part)
                          : surfaceOf(scene.primitives[static_cast<size_t>(h.id)], p, h.part);
}

inline V3 colorAt(const SceneModel& scene, const std::vector<Material>& materials, const Hit& h, V3 o, V3 d, float inv_f,
                  float* cos_out) {
  const SurfacePoint s = surfaceAt(scene, h, o, d);
  const float len = norm(d);
  const float c = std::abs(dot(s.normal, d)) / len;
  if (cos_out) *cos_out = c;
  const float footprint = h.t * len * inv_f / std::max(c, kMinFootprintCos);
  return shade(materials[static_cast<size_t>(s.material)], s, footprint);
}

}  // namespace

void parallelRows(int rows, int threads, const std::function<void(int)>& body) {
  std::atomic<int> next{0};
  auto work = [&] {
    for (;;) {
      const int start = next.fetch_add(kRowsPerChunk);
      if (start >= rows) return;
      const int end = std::min(rows, start + kRowsPerChunk);
      for (int y = start; y < end; ++y) body(y);
    }
  };
  threads = std::max(1, threads);
  std::vector<std::thread> pool;
  for (int i = 1; i < threads; ++i) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
}

RayCastImage rayCast(const SceneModel& scene, const std::vector<Material>& materials, const Intrinsics& k,
                     const Pose& camera_to_world, int threads) {
  Camera cam;
  const Eigen::Matrix3d rot = camera_to_world.linear();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) cam.r[i][j] = static_cast<float>(rot(i, j));
  const Eigen::Vector3d t = camera_to_world.translation();
  cam.origin = {static_cast<float>(t.x()), static_cast<float>(t.y()), static_cast<float>(t.z())};
  cam.fx = static_cast<float>(k.fx);
  cam.fy = static_cast<float>(k.fy);
  cam.cx = static_cast<float>(k.cx);
  cam.cy = static_cast<float>(k.cy);
  const int w = k.width, h = k.height;
  const float inv_f = 2.0f / (cam.fx + cam.fy);

  std::vector<ScreenRect> rects;
  rects.reserve(scene.primitives.size());
  for (size_t i = 0; i < scene.primitives.size(); ++i) {
    ScreenRect r{};
    if (screenRect(cam, scene.primitives[i].bounds, w, h, &r)) {
      r.index = static_cast<int>(i);
      r.near_m = distanceToBox(cam.origin, scene.primitives[i].bounds);
      rects.push_back(r);
    }
  }
  std::stable_sort(rects.begin(), rects.end(), [](const ScreenRect& a, const ScreenRect& b) { return a.near_m < b.near_m; });

  RayCastImage out;
  out.width = w;
  out.height = h;
  out.depth.assign(static_cast<size_t>(w) * h, 0.0f);
  out.cos_incidence.assign(static_cast<size_t>(w) * h, 0.0f);
  out.color.create(h, w, CV_32FC3);
  std::vector<int> hit_id(static_cast<size_t>(w) * h, kShellId);
  std::vector<int> hit_part(static_cast<size_t>(w) * h, 0);

  // Pass 1: one ray through each pixel centre.
  parallelRows(h, threads, [&](int y) {
    std::vector<ScreenRect> cands;
    cands.reserve(rects.size());
    for (const auto& r : rects)
      if (y >= r.y0 && y <= r.y1) cands.push_back(r);
    auto* row = out.color.ptr<cv::Vec3f>(y);
    for (int x = 0; x < w; ++x) {
      const V3 d = cam.rayDirection(static_cast<float>(x), static_cast<float>(y));
      const Hit hit = castRay(scene, cands.data(), static_cast<int>(cands.size()), x, cam.origin, d);
      const size_t i = static_cast<size_t>(y) * w + x;
      float c = 0;
      const V3 rgb = colorAt(scene, materials, hit, cam.origin, d, inv_f, &c);
      row[x] = {rgb.z, rgb.y, rgb.x};
      out.depth[i] = std::isfinite(hit.t) ? hit.t : 0.0f;  // t is camera z: the ray's z component is 1
      out.cos_incidence[i] = c;
      hit_id[i] = hit.id;
      hit_part[i] = hit.part;
    }
  });

  // Pass 2: 2x2 supersampled color where the surface changes between neighbours.
  parallelRows(h, threads, [&](int y) {
    std::vector<ScreenRect> cands;
    for (const auto& r : rects)
      if (y >= r.y0 && y <= r.y1) cands.push_back(r);
    auto* row = out.color.ptr<cv::Vec3f>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      bool edge = false;
      if (x + 1 < w) edge |= hit_id[i] != hit_id[i + 1] || hit_part[i] != hit_part[i + 1];
      if (x > 0) edge |= hit_id[i] != hit_id[i - 1] || hit_part[i] != hit_part[i - 1];
      if (y + 1 < h) edge |= hit_id[i] != hit_id[i + w] || hit_part[i] != hit_part[i + w];
      if (y > 0) edge |= hit_id[i] != hit_id[i - w] || hit_part[i] != hit_part[i - w];
      if (!edge) continue;
      V3 sum{0, 0, 0};
      for (int s = 0; s < 4; ++s) {
        const float px = static_cast<float>(x) + ((s & 1) ? 0.25f : -0.25f);
        const float py = static_cast<float>(y) + ((s & 2) ? 0.25f : -0.25f);
        const V3 d = cam.rayDirection(px, py);
        // Candidates of this row cover +-1 pixel, enough for quarter-pixel offsets.
        const Hit hit = castRay(scene, cands.data(), static_cast<int>(cands.size()), x, cam.origin, d);
        sum = sum + colorAt(scene, materials, hit, cam.origin, d, inv_f, nullptr);
      }
      row[x] = {sum.z * 0.25f, sum.y * 0.25f, sum.x * 0.25f};
    }
  });
  return out;
}

}  // namespace rekon::synth
