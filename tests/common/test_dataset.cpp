#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>

#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;

namespace {
// A tiny valid TUM dataset of `n` 8x6 frames.
void makeDataset(const std::string& dir, int n) {
  fs::create_directories(dir + "/rgb");
  fs::create_directories(dir + "/depth");
  std::ofstream(dir + "/camera.yaml") << "width: 8\nheight: 6\nfx: 5\nfy: 5\ncx: 3.5\ncy: 2.5\ndepth_scale: 1000\n";
  std::ofstream rgb(dir + "/rgb.txt"), depth(dir + "/depth.txt");
  rgb << "# color\n";
  for (int i = 0; i < n; ++i) {
    const std::string name = std::to_string(i) + ".png";
    cv::imwrite(dir + "/rgb/" + name, cv::Mat(6, 8, CV_8UC3, cv::Scalar(i, 2 * i, 3 * i)));
    cv::imwrite(dir + "/depth/" + name, cv::Mat(6, 8, CV_16UC1, cv::Scalar(1000 + i)));
    rgb << i * 0.1 << " rgb/" << name << "\n";
    depth << i * 0.1 + 0.005 << " depth/" << name << "\n";
  }
}
std::string errorOf(const std::string& dir) {
  try {
    rekon::TumDataset ds(dir);
    ds.load(0);
  } catch (const rekon::Error& e) {
    return e.what();
  }
  return "";
}
}  // namespace

TEST(TumDataset, AssociatesRgbAndDepthByNearestTimestamp) {
  rekon::test::TempDir dir;
  makeDataset(dir.path(), 3);
  rekon::TumDataset ds(dir.path());
  ASSERT_EQ(ds.size(), 3u);
  const auto f = ds.load(2);
  EXPECT_EQ(f.depth.at<uint16_t>(0, 0), 1002);
  EXPECT_EQ(f.color.at<cv::Vec3b>(0, 0)[2], 6);
  EXPECT_NEAR(ds.duration(), 0.2, 1e-9);
}

TEST(TumDataset, MissingCameraYamlIsNamed) {
  rekon::test::TempDir dir;
  makeDataset(dir.path(), 1);
  fs::remove(dir / "camera.yaml");
  EXPECT_NE(errorOf(dir.path()).find("camera.yaml"), std::string::npos);
}

TEST(TumDataset, MissingIndexIsNamed) {
  rekon::test::TempDir dir;
  makeDataset(dir.path(), 1);
  fs::remove(dir / "depth.txt");
  EXPECT_NE(errorOf(dir.path()).find("depth.txt"), std::string::npos);
}

TEST(TumDataset, EmptyDatasetIsAnError) {
  rekon::test::TempDir dir;
  makeDataset(dir.path(), 0);
  EXPECT_NE(errorOf(dir.path()).find("no rgb/depth pairs"), std::string::npos);
}

TEST(TumDataset, CorruptImageIsNamed) {
  rekon::test::TempDir dir;
  makeDataset(dir.path(), 1);
  std::ofstream(dir / "depth/0.png", std::ios::trunc) << "\x89PNG garbage";
  EXPECT_NE(errorOf(dir.path()).find("depth/0.png"), std::string::npos);
}

TEST(TumDataset, WrongBitDepthIsNamed) {
  rekon::test::TempDir dir;
  makeDataset(dir.path(), 1);
  cv::imwrite(dir / "depth/0.png", cv::Mat(6, 8, CV_8UC1, cv::Scalar(3)));
  EXPECT_NE(errorOf(dir.path()).find("16-bit"), std::string::npos);
}

TEST(TumDataset, MismatchedImageSizeIsNamed) {
  rekon::test::TempDir dir;
  makeDataset(dir.path(), 1);
  cv::imwrite(dir / "rgb/0.png", cv::Mat(7, 8, CV_8UC3, cv::Scalar(3)));
  EXPECT_NE(errorOf(dir.path()).find("8x7"), std::string::npos);
}

TEST(TumDataset, SevenScenesLoopReadsWithItsCameraYaml) {
  REKON_REQUIRE_DATASET(dir, "7scenes_loop_1000");
  rekon::TumDataset ds(dir);
  EXPECT_EQ(ds.size(), 1000u);
  EXPECT_TRUE(ds.hasGroundTruth());
  EXPECT_DOUBLE_EQ(ds.intrinsics().depth_scale, 1000.0);
  const auto f = ds.load(0);
  EXPECT_EQ(f.depth.cols, 640);
}
