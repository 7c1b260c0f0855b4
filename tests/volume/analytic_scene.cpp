#include "analytic_scene.hpp"

#include <cmath>
#include <limits>

namespace rekon::test {
namespace {

template <typename Hit>
void render(const Intrinsics& k, const Pose& pose, cv::Mat& depth, cv::Mat& color, Hit&& hit) {
  depth.create(k.height, k.width, CV_32FC1);
  color.create(k.height, k.width, CV_8UC3);
  const Eigen::Vector3d o = pose.translation();
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) {
      // Ray with camera z = 1, so the hit parameter is the camera depth.
      const Eigen::Vector3d d = pose.linear() * Eigen::Vector3d((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
      cv::Vec3b c(0, 0, 0);
      const double t = hit(o, d, c);
      depth.at<float>(v, u) = std::isfinite(t) ? static_cast<float>(t) : 0.f;
      color.at<cv::Vec3b>(v, u) = c;
    }
  }
}

double planeHit(const Eigen::Vector3d& o, const Eigen::Vector3d& d, int axis, double value) {
  if (std::abs(d[axis]) < 1e-12) return std::numeric_limits<double>::infinity();
  const double t = (value - o[axis]) / d[axis];
  return t > 0 ? t : std::numeric_limits<double>::infinity();
}

}  // namespace

Pose lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
  const Eigen::Vector3d z = (target - eye).normalized();
  // Looking straight along y, the y axis cannot fix the roll: use x instead.
  const Eigen::Vector3d up = std::abs(z.y()) > 0.99 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d x = up.cross(z).normalized();
  const Eigen::Vector3d y = z.cross(x);
  Pose p = Pose::Identity();
  p.linear().col(0) = x;
  p.linear().col(1) = y;
  p.linear().col(2) = z;
  p.translation() = eye;
  return p;
}

Pose orbitPose(const SphereScene& scene, double degrees, double distance) {
  const double a = degrees * M_PI / 180.0;
  const Eigen::Vector3d eye = scene.centre + distance * Eigen::Vector3d(std::sin(a), 0.0, -std::cos(a));
  return lookAt(eye, scene.centre);
}

Intrinsics smallCamera(int width, int height) {
  Intrinsics k;
  k.width = width;
  k.height = height;
  k.fx = k.fy = 0.9 * width;
  k.cx = (width - 1) / 2.0;
  k.cy = (height - 1) / 2.0;
  k.depth_scale = 1000.0;
  return k;
}

void renderSphereScene(const SphereScene& s, const Intrinsics& k, const Pose& pose, cv::Mat& depth, cv::Mat& color) {
  render(k, pose, depth, color, [&](const Eigen::Vector3d& o, const Eigen::Vector3d& d, cv::Vec3b& c) {
    double best = planeHit(o, d, 2, s.wall_z);
    c = cv::Vec3b(128, 128, 128);
    const Eigen::Vector3d oc = o - s.centre;
    const double a = d.squaredNorm(), b = 2 * oc.dot(d), cc = oc.squaredNorm() - s.radius * s.radius;
    const double disc = b * b - 4 * a * cc;
    if (disc >= 0) {
      const double t = (-b - std::sqrt(disc)) / (2 * a);
      if (t > 0 && t < best) {
        best = t;
        const Eigen::Vector3d p = o + t * d;
        c = cv::Vec3b(40, static_cast<uint8_t>(100 + 150 * (p.y() - s.centre.y() + s.radius) / (2 * s.radius)), 220);
      }
    }
    return best;
  });
}

void renderCorridor(double wall_x, double floor_y, const Intrinsics& k, const Pose& pose, cv::Mat& depth, cv::Mat& color) {
  render(k, pose, depth, color, [&](const Eigen::Vector3d& o, const Eigen::Vector3d& d, cv::Vec3b& c) {
    const double wall = planeHit(o, d, 0, wall_x), floor = planeHit(o, d, 1, floor_y);
    c = wall < floor ? cv::Vec3b(200, 160, 90) : cv::Vec3b(60, 60, 60);
    return std::min(wall, floor);
  });
}

}  // namespace rekon::test
