// The Kinect v1 depth path without the library: the disparity model, the
// depth-to-color warp on scenes with exact answers, and the calibration file.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <opencv2/core.hpp>

#include "rekon/camera/kinect_depth.hpp"
#include "rekon/common/error.hpp"
#include "test_support.hpp"

namespace rekon::camera {
namespace {

const double kC1 = std::abs(DisparityModel::kDefaultC1);

// The depth step between neighbouring raw values around `metres`.
double stepAt(const DisparityTable& table, double metres) {
  const uint16_t raw = table.nearestRaw(metres);
  return table.metres(static_cast<uint16_t>(raw + 1)) - table.metres(raw);
}

TEST(DisparityModel, TableFollowsTheBurrusFormulaAndMarksNoDepth) {
  const DisparityTable table;
  for (int raw : {0, 500, 800, 1000, 1084}) {
    const double want = 1.0 / (DisparityModel::kDefaultC0 + DisparityModel::kDefaultC1 * raw);
    EXPECT_NEAR(table.metres(static_cast<uint16_t>(raw)), want, want * 1e-6) << raw;
  }
  // 1085 * c1 exceeds c0: the denominator is negative, no depth; 2047 is the
  // Kinect's own "no value"; 2048 and up are no 11-bit values at all.
  for (int raw : {1085, 1500, 2046, 2047, 2048, 65535})
    EXPECT_EQ(table.metres(static_cast<uint16_t>(raw)), 0.0f) << raw;
}

TEST(DisparityModel, QuantisationStepGrowsWithTheSquareOfDepth) {
  const DisparityTable table;
  const double step1 = stepAt(table, 1.0), step4 = stepAt(table, 4.0);
  std::printf("quantisation step: %.3f mm at 1 m, %.3f mm at 4 m\n", 1e3 * step1, 1e3 * step4);
  // d(depth)/d(raw) = |c1| z^2: 3.07 mm at 1 m and 49.1 mm at 4 m (measured
  // 3.081 and 49.496: the step is taken from the raw value nearest z upwards,
  // where the curve is steeper).
  EXPECT_NEAR(step1, kC1 * 1.0, 0.05e-3);
  EXPECT_NEAR(step4, kC1 * 16.0, 1.5e-3);
}

TEST(DisparityModel, NearestRawRoundTripsWithinHalfAStep) {
  const DisparityTable table;
  double worst_ratio = 0.0;
  for (double z = 0.5; z <= 8.0; z += 0.0007) {
    const uint16_t raw = table.nearestRaw(z);
    ASSERT_NE(raw, DisparityTable::kNoValue) << z;
    const double error = std::abs(table.metres(raw) - z);
    // Half the step to whichever neighbour lies on z's side, plus float rounding of the table.
    const uint16_t other = static_cast<uint16_t>(table.metres(raw) < z ? raw + 1 : raw - 1);
    const double half_step = 0.5 * std::abs(table.metres(other) - table.metres(raw));
    worst_ratio = std::max(worst_ratio, error / half_step);
    ASSERT_LE(error, half_step + 1e-6 * z) << z;
  }
  std::printf("round trip 0.5..8 m: worst error %.4f of half a step\n", worst_ratio);
}

TEST(DisparityModel, DepthsNoRawValueReachesHaveNoRawValue) {
  const DisparityTable table;
  for (double z : {0.0, -1.0, std::nan(""), std::numeric_limits<double>::infinity(), 0.25, 1000.0})
    EXPECT_EQ(table.nearestRaw(z), DisparityTable::kNoValue) << z;
  // The nearest the model reaches is raw 0 = 0.3002 m; within half a step of it still counts.
  EXPECT_EQ(table.nearestRaw(table.metres(0)), 0);
}

TEST(DisparityModel, AnotherModelFromTheCalibrationIsUsed) {
  const DisparityTable table(DisparityModel{3.0, -0.003});
  EXPECT_NEAR(table.metres(500), 1.0 / 1.5, 1e-6);
  EXPECT_EQ(table.nearestRaw(1.0 / 1.5), 500);
}

// ---- registration ----

Intrinsics camera(double f) {
  return Intrinsics{640, 480, f, f, 319.5, 239.5, 1000.0};
}

cv::Mat constantDepth(float metres) {
  return cv::Mat(480, 640, CV_32FC1, cv::Scalar(metres));
}

TEST(DepthWarp, FrontoParallelPlaneLandsAtItsExactDepthAndFootprint) {
  // IR camera f = 580, color f = 525, cameras 2.5 cm apart in x, 1 cm in y
  // and 5 mm in z: a plane 2 m in front of the IR camera is 2.005 m in front
  // of the color camera at every color pixel it covers. Its footprint is the
  // IR image's corners projected into color; the color camera's smaller focal
  // length makes the warp shrink (525/580 px per px), so no pixel inside it
  // is missed.
  const Eigen::Vector3d t(-0.025, 0.01, 0.005);
  const DepthWarp warp(camera(580), camera(525), Eigen::Matrix3d::Identity(), t);
  const cv::Mat out = warp.apply(constantDepth(2.0f));
  const auto column = [&](double u_ir) {
    return std::lround(525.0 * ((u_ir - 319.5) / 580.0 * 2.0 + t.x()) / 2.005 + 319.5);
  };
  const auto row = [&](double v_ir) {
    return std::lround(525.0 * ((v_ir - 239.5) / 580.0 * 2.0 + t.y()) / 2.005 + 239.5);
  };
  const long u0 = column(0), u1 = column(639), v0 = row(0), v1 = row(479);
  ASSERT_GT(u0, 0);
  ASSERT_LT(u1, 639);
  int wrong = 0;
  for (int v = 0; v < 480; ++v) {
    for (int u = 0; u < 640; ++u) {
      const bool inside = u >= u0 && u <= u1 && v >= v0 && v <= v1;
      if (out.at<float>(v, u) != (inside ? 2.005f : 0.0f)) ++wrong;
    }
  }
  EXPECT_EQ(wrong, 0) << "footprint columns " << u0 << ".." << u1 << ", rows " << v0 << ".." << v1;
  EXPECT_EQ(toMillimetres(out).at<uint16_t>(240, 320), 2005);
}

TEST(DepthWarp, RotatedPlaneMatchesTheRayIntersectionWithinHalfAPixelOfSlope) {
  // The IR camera turned 2 degrees about y: the plane z = 2 m in front of it
  // is tilted in the color camera. Each color pixel's depth is that of a
  // point projecting within half a pixel of its centre, so it may differ from
  // the exact ray intersection by the plane's depth change over half a pixel
  // (0.07 mm here; measured worst 0.067 mm) plus the float precision of the warp.
  const double angle = 2.0 * M_PI / 180.0;
  const Eigen::Matrix3d r = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Vector3d t(-0.025, 0.0, 0.0);
  const DepthWarp warp(camera(525), camera(525), r, t);
  const cv::Mat out = warp.apply(constantDepth(2.0f));
  // The plane in the color frame: n . p = d with n = r * z_axis, d = 2 + n . t.
  const Eigen::Vector3d n = r * Eigen::Vector3d::UnitZ();
  const double d = 2.0 + n.dot(t);
  double worst = 0.0;
  int covered = 0;
  for (int v = 0; v < 480; v += 3) {
    for (int u = 0; u < 640; u += 3) {
      if (out.at<float>(v, u) == 0.0f) continue;
      ++covered;
      const Eigen::Vector3d ray((u - 319.5) / 525.0, (v - 239.5) / 525.0, 1.0);
      worst = std::max(worst, std::abs(out.at<float>(v, u) - d / n.dot(ray)));
    }
  }
  std::printf("rotated plane: worst depth error %.4f mm over %d pixels\n", 1e3 * worst, covered);
  EXPECT_GT(covered, 30000);  // measured 32 788 of the 34 240 sampled pixels: 2 degrees turn the rest out of view
  EXPECT_LT(worst, 0.1e-3);
}

TEST(DepthWarp, NearestSurfaceWinsAndDisocclusionStaysEmpty) {
  // A 40-pixel-wide bar 1 m away in front of a wall 3 m away; the color
  // camera 5 cm to the right: the bar shifts 26.25 px left, the wall 8.75 px.
  cv::Mat depth = constantDepth(3.0f);
  depth.colRange(300, 340).setTo(1.0f);
  const DepthWarp warp(camera(525), camera(525), Eigen::Matrix3d::Identity(), Eigen::Vector3d(-0.05, 0.0, 0.0));
  const cv::Mat out = warp.apply(depth);
  // Bar columns 300..339 land on 274..313 (x - 26.25, rounded); wall columns
  // 283..322 land there too (x - 8.75) but are behind it.
  for (int u = 274; u <= 313; ++u) EXPECT_EQ(out.at<float>(240, u), 1.0f) << u;
  // Color columns 314..330 look at wall hidden by the bar from the IR camera.
  for (int u = 314; u <= 330; ++u) EXPECT_EQ(out.at<float>(240, u), 0.0f) << u;
  EXPECT_EQ(out.at<float>(240, 331), 3.0f);
  EXPECT_EQ(out.at<float>(240, 273), 3.0f);
}

TEST(KinectRegistration, AlignedDepthKeepsEveryPixel) {
  KinectCalibration c;
  c.color = camera(525);
  c.depth = c.color;
  cv::Mat raw(480, 640, CV_16UC1, cv::Scalar(DisparityTable::kNoValue));
  raw.at<uint16_t>(10, 20) = 700;  // 1/(3.33095 - 2.14977) = 0.8466 m
  raw.at<uint16_t>(479, 639) = 0;  // 0.3002 m
  const cv::Mat mm = KinectRegistration(c).apply(raw);
  EXPECT_EQ(mm.at<uint16_t>(10, 20), 847);
  EXPECT_EQ(mm.at<uint16_t>(479, 639), 300);
  EXPECT_EQ(cv::countNonZero(mm), 2);
  EXPECT_THROW(KinectRegistration(c).apply(cv::Mat(240, 320, CV_16UC1, cv::Scalar(0))), Error);
}

// ---- calibration file ----

const char* const kColor = "width: 640\nheight: 480\nfx: 520\nfy: 521\ncx: 318\ncy: 241\ndepth_scale: 1000\n";

TEST(KinectCalibration, FileWithoutDepthKeysIsAligned) {
  const KinectCalibration c = parseKinectCalibration(kColor, "cam.yaml");
  EXPECT_TRUE(c.aligned);
  EXPECT_EQ(c.depth.fx, 520.0);
  EXPECT_EQ(c.disparity.c0, DisparityModel::kDefaultC0);
  // The one-line form of common/camera.hpp works too.
  EXPECT_TRUE(parseKinectCalibration("640 480 585 585 320 240 1000", "cam.yaml").aligned);
}

TEST(KinectCalibration, SavedFileReadsBackTheSame) {
  KinectCalibration c = KinectCalibration::nominal();
  c.depth_to_color_rotation = Eigen::AngleAxisd(0.01, Eigen::Vector3d(0.3, 0.9, 0.1).normalized()).toRotationMatrix();
  c.disparity = DisparityModel{3.2, -0.0031};
  test::TempDir dir;
  saveKinectCalibration(c, dir / "camera.yaml");
  const KinectCalibration back = loadKinectCalibration(dir / "camera.yaml");
  EXPECT_FALSE(back.aligned);
  EXPECT_EQ(back.depth.fx, 580.0);
  EXPECT_EQ(back.color.fx, 525.0);
  EXPECT_NEAR((back.depth_to_color_rotation - c.depth_to_color_rotation).cwiseAbs().maxCoeff(), 0.0, 1e-11);
  EXPECT_EQ(back.depth_to_color_translation, c.depth_to_color_translation);
  EXPECT_EQ(back.disparity.c1, -0.0031);
}

// Parsing `extra` after the color keys fails with one line naming the file and `key`.
void expectError(const std::string& extra, const std::string& key) {
  try {
    parseKinectCalibration(std::string(kColor) + extra, "cam.yaml");
    ADD_FAILURE() << "no error for: " << extra;
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.rfind("cam.yaml", 0), 0u) << what;
    EXPECT_NE(what.find(key), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
  }
}

TEST(KinectCalibration, BadValuesAreOneLineNamingFileAndKey) {
  const std::string depth = "depth_camera: {fx: 580, fy: 580, cx: 320, cy: 240}\n";
  expectError(depth + "depth_to_color_rotation: [1, 0, 0, 0, 1, 0]\n", "depth_to_color_rotation must be 9 numbers");
  expectError(depth + "depth_to_color_rotation: [1, 0, 0, 0, 1, 0, 0, 0, 2]\n",
              "depth_to_color_rotation is not a rotation");
  expectError(depth + "depth_to_color_rotation: [-1, 0, 0, 0, 1, 0, 0, 0, 1]\n", "not a rotation");  // a reflection
  expectError(depth + "depth_to_color_translation: [25, 0, 0]\n", "give it in metres");
  expectError(depth + "depth_to_color_translation: [0.025, abc, 0]\n",
              "depth_to_color_translation[1] = 'abc' is not a number");
  expectError(depth + "depth_to_color_translation: 0.025\n", "depth_to_color_translation must be 3 numbers");
  expectError("depth_camera: {fx: 580, fy: 580, cx: 320}\n", "depth_camera.cy");
  expectError("depth_camera: {fx: -580, fy: 580, cx: 320, cy: 240}\n", "fx");
  expectError("depth_camera: {fx: 580, fy: 580, cx: 320, cy: 240, width: 320}\n", "depth_camera.width");
  expectError("depth_camera: 580\n", "depth_camera must be a mapping");
  expectError("depth_to_color_translation: [0.025, 0, 0]\n", "depth_to_color_translation needs depth_camera");
  expectError("disparity: [3.33, 0.003]\n", "disparity must be [c0, c1] with c0 > 0 and c1 < 0");
  expectError("disparity: [3.33]\n", "disparity must be 2 numbers");
  expectError("disparity: [.nan, -0.003]\n", "disparity[0] = '.nan' is not finite");
}

TEST(KinectCalibration, MissingFileNamesItAndTheOption) {
  try {
    loadKinectCalibration("/nonexistent/camera.yaml");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "/nonexistent/camera.yaml: cannot read the calibration file; check the --calibration"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace rekon::camera
