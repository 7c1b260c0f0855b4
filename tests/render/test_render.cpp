// `renderMesh` and `rekon render`: offscreen images of colored meshes.
#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rekon/common/error.hpp"
#include "rekon/render/render.hpp"
#include "test_support.hpp"

namespace {

using rekon::Mesh;
using rekon::render::RenderOptions;

// A unit cube centred at `c`, outward winding, every vertex of color `rgb`.
Mesh cube(const Eigen::Vector3f& c, std::array<uint8_t, 3> rgb) {
  Mesh m;
  for (int i = 0; i < 8; ++i) {
    m.vertices.push_back(c + Eigen::Vector3f((i & 1) ? 0.5f : -0.5f, (i & 2) ? 0.5f : -0.5f, (i & 4) ? 0.5f : -0.5f));
    m.colors.push_back(rgb);
  }
  const int faces[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& f : faces) {
    m.triangles.emplace_back(f[0], f[1], f[2]);
    m.triangles.emplace_back(f[0], f[2], f[3]);
  }
  return m;
}

bool isBackground(const cv::Vec3b& px, const RenderOptions& o) { return px == o.background; }

TEST(Render, AutoViewShowsTheMeshInTheCentre) {
  RenderOptions o;
  o.width = 320;
  o.height = 240;
  const cv::Mat image = rekon::render::renderMesh(cube({10, -3, 2}, {255, 0, 0}), o);
  ASSERT_EQ(image.type(), CV_8UC3);
  ASSERT_EQ(image.cols, 320);
  const cv::Vec3b centre = image.at<cv::Vec3b>(120, 160);
  EXPECT_FALSE(isBackground(centre, o));
  EXPECT_GT(centre[2], 50);  // red (BGR), lit
  EXPECT_EQ(centre[0], 0);
  // The whole cube fits: the border stays background.
  for (int x = 0; x < image.cols; ++x) EXPECT_TRUE(isBackground(image.at<cv::Vec3b>(0, x), o));
}

// A 1 m square floor of 100 x 100 vertices, and a stray triangle 40 m away
// (as 7-Scenes' mesh has a few far-off fragments): the view frames the floor.
TEST(Render, AutoViewFramesTheBulkNotAStrayFragment) {
  Mesh m;
  const int n = 100;
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      m.vertices.emplace_back(static_cast<float>(x) / (n - 1), static_cast<float>(y) / (n - 1), 0.0f);
      m.colors.push_back({200, 200, 200});
    }
  }
  for (int y = 0; y + 1 < n; ++y) {
    for (int x = 0; x + 1 < n; ++x) {
      const int i = y * n + x;
      m.triangles.emplace_back(i, i + 1, i + n + 1);
      m.triangles.emplace_back(i, i + n + 1, i + n);
    }
  }
  const int stray = static_cast<int>(m.vertices.size());
  for (const Eigen::Vector3f& v : {Eigen::Vector3f(40, 40, 5), Eigen::Vector3f(40.1f, 40, 5), Eigen::Vector3f(40, 40.1f, 5)}) {
    m.vertices.push_back(v);
    m.colors.push_back({200, 200, 200});
  }
  m.triangles.emplace_back(stray, stray + 1, stray + 2);
  RenderOptions o;
  o.width = 320;
  o.height = 240;
  o.up = Eigen::Vector3d::UnitZ();
  const cv::Mat image = rekon::render::renderMesh(m, o);
  int covered = 0;
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) covered += !isBackground(image.at<cv::Vec3b>(y, x), o);
  }
  // Framed by every vertex, the floor covered 0.1 % of the image; by the bulk, 20 % or more.
  EXPECT_GT(covered, image.rows * image.cols / 5) << covered << " pixels of " << image.rows * image.cols;
}

TEST(Render, AnExplicitViewLooksAtItsTarget) {
  RenderOptions o;
  o.width = 200;
  o.height = 200;
  o.view = rekon::render::View{Eigen::Vector3d(0, 0, 5), Eigen::Vector3d(3, 0, 0)};
  o.up = Eigen::Vector3d::UnitY();
  const cv::Mat image = rekon::render::renderMesh(cube({3, 0, 0}, {0, 255, 0}), o);
  EXPECT_FALSE(isBackground(image.at<cv::Vec3b>(100, 100), o));
  EXPECT_TRUE(isBackground(image.at<cv::Vec3b>(5, 5), o));
}

TEST(Render, BackFacesAreCulledSoARoomShowsItsInside) {
  // A blue room (inward-facing box of 4 m) with a red box inside, seen from
  // outside: culling back faces removes the near wall and shows the red box;
  // without culling the near wall hides it.
  Mesh scene = cube({0, 0, 0}, {0, 0, 255});
  for (auto& v : scene.vertices) v *= 4.0f;
  for (auto& t : scene.triangles) std::swap(t[1], t[2]);  // normals inwards
  const Mesh inside = cube({0, 0, 0}, {255, 0, 0});
  for (const auto& t : inside.triangles) scene.triangles.emplace_back(t + Eigen::Vector3i::Constant(8));
  scene.vertices.insert(scene.vertices.end(), inside.vertices.begin(), inside.vertices.end());
  scene.colors.insert(scene.colors.end(), inside.colors.begin(), inside.colors.end());
  RenderOptions o;
  o.width = 160;
  o.height = 120;
  o.view = rekon::render::View{Eigen::Vector3d(6, 0.5, 1), Eigen::Vector3d(0, 0, 0)};
  const cv::Vec3b culled = rekon::render::renderMesh(scene, o).at<cv::Vec3b>(60, 80);
  o.cull = rekon::render::Cull::None;
  const cv::Vec3b all = rekon::render::renderMesh(scene, o).at<cv::Vec3b>(60, 80);
  EXPECT_GT(culled[2], 0);  // red (BGR)
  EXPECT_EQ(culled[0], 0);
  EXPECT_GT(all[0], 0);  // blue
  EXPECT_EQ(all[2], 0);
}

TEST(Render, ColorMapRunsFromBlueToRed) {
  const auto c = rekon::render::colorMap({0.0f, 0.025f, 0.05f, 1.0f}, 0.0f, 0.05f);
  EXPECT_EQ(c[0], (std::array<uint8_t, 3>{0, 0, 255}));
  EXPECT_EQ(c[1], (std::array<uint8_t, 3>{0, 255, 0}));
  EXPECT_EQ(c[2], (std::array<uint8_t, 3>{255, 0, 0}));
  EXPECT_EQ(c[3], c[2]);  // clamped
}

TEST(RenderCommand, WritesANonEmptyPngWhoseCentreShowsTheMesh) {
  rekon::test::TempDir dir;
  rekon::writePly(cube({0, 0, 0}, {200, 180, 40}), dir / "cube.ply");
  std::string out;
  ASSERT_EQ(rekon::test::runCommand(rekon::test::binDir() + "/rekon render " + (dir / "cube.ply") + " --out " +
                                        (dir / "cube.png") + " --width 256 --height 192",
                                    &out),
            0)
      << out;
  const cv::Mat image = cv::imread(dir / "cube.png", cv::IMREAD_COLOR);
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, 256);
  EXPECT_NE(image.at<cv::Vec3b>(96, 128), cv::Vec3b(235, 235, 235));
  EXPECT_NE(out.find("coverage="), std::string::npos) << out;
}

// A strip of `rgb` at height y (camera frame: y down), across x at depth 3 m, seen from both sides.
void addStrip(Mesh& m, float y, std::array<uint8_t, 3> rgb) {
  const int i = static_cast<int>(m.vertices.size());
  for (const auto& v : {Eigen::Vector3f(-1, y - 0.2f, 3), Eigen::Vector3f(1, y - 0.2f, 3), Eigen::Vector3f(1, y + 0.2f, 3),
                        Eigen::Vector3f(-1, y + 0.2f, 3)}) {
    m.vertices.push_back(v);
    m.colors.push_back(rgb);
  }
  for (const auto& t : {Eigen::Vector3i(i, i + 1, i + 2), Eigen::Vector3i(i, i + 2, i + 3), Eigen::Vector3i(i, i + 2, i + 1),
                        Eigen::Vector3i(i, i + 3, i + 2)})
    m.triangles.push_back(t);
}

// Mean row and column of the pixels that are mostly `channel` (BGR index).
cv::Point2d centroidOf(const cv::Mat& image, int channel) {
  cv::Point2d sum(0, 0);
  int n = 0;
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) {
      const cv::Vec3b p = image.at<cv::Vec3b>(y, x);
      if (p[channel] > 60 && p[channel] > 2 * p[(channel + 1) % 3] && p[channel] > 2 * p[(channel + 2) % 3]) {
        sum += cv::Point2d(x, y);
        ++n;
      }
    }
  }
  return n ? sum / n : cv::Point2d(-1, -1);
}

// Issue 27: rekon's meshes are in the first camera's frame (y down); the
// default view was tilted (up z). A red strip above a green one in that
// frame (smaller y) is drawn above it, one over the other, without flags.
TEST(RenderCommand, DefaultViewShowsACameraFrameMeshUpright) {
  rekon::test::TempDir dir;
  Mesh m;
  addStrip(m, -1.0f, {255, 0, 0});  // up (a ceiling)
  addStrip(m, 1.0f, {0, 255, 0});   // down (a floor)
  rekon::writePly(m, dir / "strips.ply");
  const auto render = [&](const std::string& extra) {
    const std::string png = dir / "strips.png";
    EXPECT_EQ(rekon::test::runCommand(rekon::test::binDir() + "/rekon render " + (dir / "strips.ply") + " --out " + png +
                                      " --width 320 --height 240" + extra + " > /dev/null 2>&1"), 0);
    return cv::imread(png, cv::IMREAD_COLOR);
  };
  const auto upright = [](const cv::Mat& image) {
    const cv::Point2d red = centroidOf(image, 2), green = centroidOf(image, 1);
    return red.y >= 0 && green.y >= 0 && green.y - red.y > 0.2 * image.rows && std::abs(green.x - red.x) < 0.1 * image.cols;
  };
  EXPECT_TRUE(upright(render("")));
  EXPECT_FALSE(upright(render(" --up z")));  // the old default: what the test tells apart
}

TEST(RenderCommand, RejectsAMalformedView) {
  rekon::test::TempDir dir;
  rekon::writePly(cube({0, 0, 0}, {1, 2, 3}), dir / "cube.ply");
  std::string out;
  EXPECT_NE(rekon::test::runCommand(rekon::test::binDir() + "/rekon render " + (dir / "cube.ply") + " --out " + (dir / "x.png") +
                                        " --view 1,2,3",
                                    &out),
            0);
  EXPECT_NE(out.find("x,y,z,tx,ty,tz"), std::string::npos) << out;
}

}  // namespace
