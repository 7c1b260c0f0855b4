#pragma once
// Exact depth and color images of simple analytic scenes (a sphere before a
// wall; a corridor wall) for the volume tests.
#include <opencv2/core/mat.hpp>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"

namespace rekon::test {

struct SphereScene {
  Eigen::Vector3d centre{0.0, 0.0, 2.0};
  double radius = 0.3;
  double wall_z = 2.8;  // a wall z = wall_z behind the sphere
};

// A camera at `eye` looking at `target` (x right, y down, z forward).
Pose lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target);
// Camera on a horizontal circle of radius `distance` around the sphere centre, `degrees` from the -z side.
Pose orbitPose(const SphereScene& scene, double degrees, double distance = 1.2);

Intrinsics smallCamera(int width = 160, int height = 120);

// Depth in metres (CV_32F, 0 = no surface) and BGR color (sphere reddish with
// a gradient, wall gray).
void renderSphereScene(const SphereScene& scene, const Intrinsics& k, const Pose& camera_to_world, cv::Mat& depth,
                       cv::Mat& color);
// A wall x = wall_x and a floor y = floor_y, infinite along z.
void renderCorridor(double wall_x, double floor_y, const Intrinsics& k, const Pose& camera_to_world, cv::Mat& depth,
                    cv::Mat& color);

}  // namespace rekon::test
