#pragma once
// Offscreen CPU rendering of a colored triangle mesh: a z-buffer rasteriser
// with Lambert lighting of the vertex colors, for `rekon render` and reports.
// No window and no GPU.
#include <opencv2/core/mat.hpp>

#include <optional>
#include <string>
#include <vector>

#include "rekon/common/mesh.hpp"
#include "rekon/common/pose.hpp"

namespace rekon::render {

// Triangles are front-facing when counter-clockwise seen from the viewer (their
// winding normal points at the viewer). Back faces are culled by default, so
// a room seen from outside shows its inside through the near walls.
enum class Cull { Back, Front, None };

struct View {
  Eigen::Vector3d eye = Eigen::Vector3d(0, 0, 1);
  Eigen::Vector3d target = Eigen::Vector3d::Zero();
};

struct RenderOptions {
  static constexpr int kDefaultWidth = 1024;
  static constexpr int kDefaultHeight = 768;
  static constexpr double kDefaultFovYDeg = 45.0;
  int width = kDefaultWidth;
  int height = kDefaultHeight;
  double fov_y_deg = kDefaultFovYDeg;
  std::optional<View> view;                    // empty: autoView()
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();  // world up of the mesh
  Cull cull = Cull::Back;
  int supersampling = 2;  // rendered at this factor, then averaged down (anti-aliasing)
  cv::Vec3b background{235, 235, 235};  // BGR
};

// A viewpoint above and in front of the mesh that frames all of it.
View autoView(const Mesh& mesh, const RenderOptions& options);

// The camera-to-world pose of a view (camera x right, y down, z forward).
Pose viewPose(const View& view, const Eigen::Vector3d& up);

// CV_8UC3 BGR image. An empty mesh gives the background only.
cv::Mat renderMesh(const Mesh& mesh, const RenderOptions& options = {});

// Per-vertex colors from values through a blue-green-red color map
// (lo = blue, hi = red), e.g. distances to the ground truth as in the paper's Figure 6.
std::vector<std::array<uint8_t, 3>> colorMap(const std::vector<float>& values, float lo, float hi);

// `rekon render MESH --out FILE.png [--view auto|x,y,z,tx,ty,tz] ...`
int renderCommand(int argc, char** argv);

}  // namespace rekon::render
