#include <Eigen/Eigenvalues>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "rekon/common/error.hpp"
#include "rekon/render/render.hpp"

namespace rekon::render {
namespace {

constexpr float kAmbient = 0.3f;
constexpr float kDiffuse = 0.7f;
// Margin kept between the mesh and the image border by autoView.
constexpr double kFrameFill = 0.94;
constexpr size_t kMaxFramingVertices = 200000;
// autoView frames this share of the vertices (along each axis and in the
// image), so that a few stray fragments do not shrink the scan to a corner.
constexpr double kFramedShare = 0.995;
const cv::Vec3f kDefaultVertexColor{200, 200, 200};

struct ClipVertex {
  Eigen::Vector3f p;  // camera frame
  cv::Vec3f c;        // BGR, already lit
};

struct Target {
  int w, h;
  float f, cx, cy;
  std::vector<float> inv_depth;  // 0 = empty
  std::vector<cv::Vec3f> color;
};

void rasterise(Target& t, const ClipVertex& a, const ClipVertex& b, const ClipVertex& c) {
  const float iz0 = 1.0f / a.p.z(), iz1 = 1.0f / b.p.z(), iz2 = 1.0f / c.p.z();
  const float x0 = t.f * a.p.x() * iz0 + t.cx, y0 = t.f * a.p.y() * iz0 + t.cy;
  const float x1 = t.f * b.p.x() * iz1 + t.cx, y1 = t.f * b.p.y() * iz1 + t.cy;
  const float x2 = t.f * c.p.x() * iz2 + t.cx, y2 = t.f * c.p.y() * iz2 + t.cy;
  const float area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0);
  if (std::abs(area) < 1e-12f) return;
  const float inv_area = 1.0f / area;
  const int xa = std::max(0, static_cast<int>(std::floor(std::min({x0, x1, x2}))));
  const int xb = std::min(t.w - 1, static_cast<int>(std::ceil(std::max({x0, x1, x2}))));
  const int ya = std::max(0, static_cast<int>(std::floor(std::min({y0, y1, y2}))));
  const int yb = std::min(t.h - 1, static_cast<int>(std::ceil(std::max({y0, y1, y2}))));
  const cv::Vec3f c0 = a.c * iz0, c1 = b.c * iz1, c2 = c.c * iz2;
  for (int y = ya; y <= yb; ++y) {
    const float py = static_cast<float>(y) + 0.5f;
    for (int x = xa; x <= xb; ++x) {
      const float px = static_cast<float>(x) + 0.5f;
      // Barycentric weights by edge functions (sign-normalised by the area).
      const float w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) * inv_area;
      const float w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) * inv_area;
      const float w2 = 1.0f - w0 - w1;
      if (w0 < 0 || w1 < 0 || w2 < 0) continue;
      const float iz = w0 * iz0 + w1 * iz1 + w2 * iz2;
      const size_t i = static_cast<size_t>(y) * t.w + x;
      if (iz <= t.inv_depth[i]) continue;
      t.inv_depth[i] = iz;
      t.color[i] = (c0 * w0 + c1 * w1 + c2 * w2) * (1.0f / iz);
    }
  }
}

// Sutherland-Hodgman against the near plane z = near; at most 4 vertices come out.
int clipNear(const ClipVertex in[3], float near, ClipVertex out[4]) {
  int n = 0;
  for (int i = 0; i < 3; ++i) {
    const ClipVertex& p = in[i];
    const ClipVertex& q = in[(i + 1) % 3];
    const bool p_in = p.p.z() >= near, q_in = q.p.z() >= near;
    if (p_in) out[n++] = p;
    if (p_in != q_in) {
      const float s = (near - p.p.z()) / (q.p.z() - p.p.z());
      out[n++] = {p.p + s * (q.p - p.p), p.c + s * (q.c - p.c)};
    }
  }
  return n;
}

Eigen::Vector3d safeUp(const Eigen::Vector3d& forward, const Eigen::Vector3d& up) {
  if (forward.cross(up).norm() > 1e-6 * up.norm()) return up;
  return std::abs(forward.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
}

}  // namespace

Pose viewPose(const View& view, const Eigen::Vector3d& up) {
  const Eigen::Vector3d d = view.target - view.eye;
  if (!(d.norm() > 0) || !d.allFinite()) throw Error("render view: eye and target must be distinct finite points");
  const Eigen::Vector3d forward = d.normalized();
  const Eigen::Vector3d right = forward.cross(safeUp(forward, up)).normalized();
  Pose pose = Pose::Identity();
  pose.linear().col(0) = right;
  pose.linear().col(1) = forward.cross(right);
  pose.linear().col(2) = forward;
  pose.translation() = view.eye;
  return pose;
}

View autoView(const Mesh& mesh, const RenderOptions& options) {
  if (mesh.vertices.empty()) return {};
  // The bulk of the vertices, not every one: a few stray fragments far off
  // (7-Scenes' mesh has some) left the room 9 % of the image.
  const size_t step = std::max<size_t>(1, mesh.vertices.size() / kMaxFramingVertices);
  std::vector<Eigen::Vector3f> sample;
  for (size_t i = 0; i < mesh.vertices.size(); i += step) sample.push_back(mesh.vertices[i]);
  const auto quantile = [](std::vector<double>& values, double q) {
    const size_t k = std::min(values.size() - 1, static_cast<size_t>(q * static_cast<double>(values.size())));
    std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
    return values[k];
  };
  Eigen::Vector3d lo, hi;
  std::vector<double> values(sample.size());
  for (int axis = 0; axis < 3; ++axis) {
    for (size_t i = 0; i < sample.size(); ++i) values[i] = sample[i][axis];
    lo[axis] = quantile(values, 1.0 - kFramedShare);
    hi[axis] = quantile(values, kFramedShare);
  }
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  const double radius = std::max(1e-6, 0.5 * (hi - lo).norm());
  // Look down at about 40 degrees from an oblique corner of the mesh's own
  // horizontal axes (e1 its longest), so that a room lies along the image
  // rather than across its diagonal.
  const Eigen::Vector3d up = options.up.normalized();
  const Eigen::Vector3d ref = std::abs(up.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d a = up.cross(ref).normalized(), b = up.cross(a);
  Eigen::Matrix2d spread = Eigen::Matrix2d::Zero();
  for (const Eigen::Vector3f& v : sample) {
    const Eigen::Vector3d d = v.cast<double>() - centre;
    const Eigen::Vector2d p(d.dot(a), d.dot(b));
    spread += p * p.transpose();
  }
  const Eigen::Vector2d major = Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(spread).eigenvectors().col(1);
  const Eigen::Vector3d e1 = (major.x() * a + major.y() * b).normalized(), e2 = up.cross(e1);
  const Eigen::Vector3d dir = (-0.55 * e1 - 0.85 * e2 + 0.85 * up).normalized();
  const double tan_y = std::tan(0.5 * options.fov_y_deg * std::numbers::pi / 180.0);
  const double tan_x = tan_y * options.width / options.height;
  View v;
  v.target = centre;
  v.eye = centre + dir * (radius / std::sin(std::atan(std::min(tan_x, tan_y))));
  // Then slide along the view direction until the bulk of the vertices just fits.
  const Pose world_to_cam = viewPose(v, up).inverse();
  for (size_t i = 0; i < sample.size(); ++i) {
    const Eigen::Vector3d p = world_to_cam * sample[i].cast<double>();
    values[i] = std::max(std::abs(p.x()) / (kFrameFill * tan_x) - p.z(), std::abs(p.y()) / (kFrameFill * tan_y) - p.z());
  }
  v.eye += dir * quantile(values, kFramedShare);  // moving back by the shift adds it to every vertex's depth
  return v;
}

cv::Mat renderMesh(const Mesh& mesh, const RenderOptions& options) {
  if (options.width <= 0 || options.height <= 0 || options.width > 16384 || options.height > 16384) {
    throw Error("render: image size " + std::to_string(options.width) + "x" + std::to_string(options.height) +
                " is invalid; give 1 to 16384 pixels a side");
  }
  if (!(options.fov_y_deg > 1 && options.fov_y_deg < 170)) throw Error("render: field of view must be between 1 and 170 degrees");
  const int ss = std::clamp(options.supersampling, 1, 4);
  const View view = options.view ? *options.view : autoView(mesh, options);
  const Pose world_to_cam = viewPose(view, options.up).inverse();

  Target t;
  t.w = options.width * ss;
  t.h = options.height * ss;
  t.f = static_cast<float>(0.5 * t.h / std::tan(0.5 * options.fov_y_deg * std::numbers::pi / 180.0));
  t.cx = 0.5f * static_cast<float>(t.w);
  t.cy = 0.5f * static_cast<float>(t.h);
  t.inv_depth.assign(static_cast<size_t>(t.w) * t.h, 0.0f);
  t.color.assign(static_cast<size_t>(t.w) * t.h, cv::Vec3f(options.background[0], options.background[1], options.background[2]));

  std::vector<Eigen::Vector3f> cam(mesh.vertices.size());
  const Eigen::Matrix3f r = world_to_cam.linear().cast<float>();
  const Eigen::Vector3f tr = world_to_cam.translation().cast<float>();
  for (size_t i = 0; i < cam.size(); ++i) cam[i] = r * mesh.vertices[i] + tr;
  const float near = static_cast<float>(std::max(1e-4, 1e-4 * (view.eye - view.target).norm()));
  // Key light from above-left of the viewer (camera frame: x right, y down, z forward).
  const Eigen::Vector3f light = Eigen::Vector3f(-0.35f, -0.6f, -1.0f).normalized();
  const bool colored = mesh.colors.size() == mesh.vertices.size();

  for (const auto& tri : mesh.triangles) {
    const size_t ia = static_cast<size_t>(tri[0]), ib = static_cast<size_t>(tri[1]), ic = static_cast<size_t>(tri[2]);
    if (ia >= cam.size() || ib >= cam.size() || ic >= cam.size()) throw Error("render: a triangle refers to a missing vertex");
    const Eigen::Vector3f &a = cam[ia], &b = cam[ib], &c = cam[ic];
    if (a.z() < near && b.z() < near && c.z() < near) continue;
    Eigen::Vector3f n = (b - a).cross(c - a);
    const float facing = n.dot(a);  // < 0: the winding normal points at the viewer
    if (options.cull == Cull::Back && facing >= 0) continue;
    if (options.cull == Cull::Front && facing < 0) continue;
    const float len = n.norm();
    if (!(len > 0)) continue;
    const float shade = kAmbient + kDiffuse * std::abs(n.dot(light)) / len;  // two-sided
    auto vcolor = [&](size_t i) {
      if (!colored) return kDefaultVertexColor * shade;
      const auto& rgb = mesh.colors[i];
      return cv::Vec3f(rgb[2], rgb[1], rgb[0]) * shade;
    };
    const ClipVertex in[3] = {{a, vcolor(ia)}, {b, vcolor(ib)}, {c, vcolor(ic)}};
    ClipVertex poly[4];
    const int count = clipNear(in, near, poly);
    for (int k = 1; k + 1 < count; ++k) rasterise(t, poly[0], poly[k], poly[k + 1]);
  }

  cv::Mat big(t.h, t.w, CV_32FC3, t.color.data());
  cv::Mat out;
  if (ss > 1) {
    cv::Mat small;
    cv::resize(big, small, cv::Size(options.width, options.height), 0, 0, cv::INTER_AREA);
    small.convertTo(out, CV_8UC3);
  } else {
    big.convertTo(out, CV_8UC3);
  }
  return out;
}

std::vector<std::array<uint8_t, 3>> colorMap(const std::vector<float>& values, float lo, float hi) {
  std::vector<std::array<uint8_t, 3>> out(values.size());
  const float span = hi > lo ? hi - lo : 1.0f;
  for (size_t i = 0; i < values.size(); ++i) {
    const float x = std::clamp((values[i] - lo) / span, 0.0f, 1.0f);
    // Blue -> cyan -> green -> yellow -> red.
    const float r = std::clamp(std::min(4 * x - 2, 1.0f), 0.0f, 1.0f);
    const float g = std::clamp(x < 0.25f ? 4 * x : (x > 0.75f ? 4 - 4 * x : 1.0f), 0.0f, 1.0f);
    const float b = std::clamp(std::min(2 - 4 * x, 1.0f), 0.0f, 1.0f);
    out[i] = {static_cast<uint8_t>(std::lround(255 * r)), static_cast<uint8_t>(std::lround(255 * g)),
              static_cast<uint8_t>(std::lround(255 * b))};
  }
  return out;
}

}  // namespace rekon::render
