#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <utility>
#include <vector>

#include "rekon/common/camera.hpp"
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

TEST(TumDataset, ASubsetListsTheKeptFramesWhereTheyAreUnderTheirRgbTimestamps) {
  rekon::test::TempDir dir;
  makeDataset(dir.path() + "/all", 5);
  std::ofstream(dir.path() + "/all/groundtruth.txt") << "0 0 0 0 0 0 0 1\n";
  const rekon::TumDataset all(dir.path() + "/all");
  ASSERT_EQ(all.writeSubset(dir.path() + "/some", [](size_t i) { return i != 1 && i != 2; }), 3u);

  const rekon::TumDataset some(dir.path() + "/some");
  ASSERT_EQ(some.size(), 3u);
  for (const auto& [kept, of] : {std::pair{0u, 0u}, std::pair{1u, 3u}, std::pair{2u, 4u}}) {
    EXPECT_DOUBLE_EQ(some.timestamp(kept), all.timestamp(of));
    const auto f = some.load(kept);
    EXPECT_EQ(f.depth.at<uint16_t>(0, 0), 1000 + of);
    EXPECT_EQ(f.color.at<cv::Vec3b>(0, 0)[2], 3 * of);
  }
  EXPECT_TRUE(some.hasGroundTruth());
  EXPECT_EQ(some.intrinsics().fx, all.intrinsics().fx);
}

TEST(TumDataset, ASubsetThatCannotBeWrittenIsOneErrorNamingTheFolder) {
  rekon::test::TempDir dir;
  makeDataset(dir.path() + "/all", 2);
  std::ofstream(dir.path() + "/file") << "not a folder\n";
  const rekon::TumDataset all(dir.path() + "/all");
  try {
    all.writeSubset(dir.path() + "/file/some", [](size_t) { return true; });
    FAIL() << "a subset under a file was written";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find(dir.path() + "/file/some: cannot create the folder"), std::string::npos) << e.what();
  }
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

// camera.yaml: the keyed form and the one-line form README.md documents give
// the same intrinsics; anything else is a rekon::Error naming the file and the
// forms (a one-line file used to throw YAML::BadSubscript: std::terminate).
TEST(CameraYaml, KeyedAndOneLineFormsAgree) {
  const rekon::Intrinsics keyed = rekon::parseIntrinsics(
      "width: 640\nheight: 480\nfx: 585\nfy: 585.5\ncx: 320\ncy: 240\ndepth_scale: 1000\n", "keyed.yaml");
  const rekon::Intrinsics line = rekon::parseIntrinsics("640 480 585 585.5 320 240 1000\n", "line.yaml");
  for (const rekon::Intrinsics& k : {keyed, line}) {
    EXPECT_EQ(k.width, 640);
    EXPECT_EQ(k.height, 480);
    EXPECT_EQ(k.fx, 585.0);
    EXPECT_EQ(k.fy, 585.5);
    EXPECT_EQ(k.cx, 320.0);
    EXPECT_EQ(k.cy, 240.0);
    EXPECT_EQ(k.depth_scale, 1000.0);
  }
}

TEST(CameraYaml, EveryOtherFormIsOneErrorNamingTheFileAndTheForms) {
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"", "neither a mapping"},
      {"640 480 585 585 320 240\n", "6 values"},
      {"640 480 585 585 320 240 1000 7\n", "8 values"},
      {"[640, 480, 585, 585, 320, 240, 1000]\n", "neither a mapping"},
      {"640 480 five 585 320 240 1000\n", "fx = 'five'"},
      {"640.5 480 585 585 320 240 1000\n", "whole number"},
      {"width: 640\nheight: 480\nfx: 585\nfy: 585\ncx: 320\ncy: 240\n", "missing key 'depth_scale'"},
      {"width: [640]\nheight: 480\nfx: 585\nfy: 585\ncx: 320\ncy: 240\ndepth_scale: 1\n", "'width' is not a number"},
      {"width: [640\n", "not valid YAML"},
      {"640 480 nan 585 320 240 1000\n", "fx"},
      {"1e300 480 585 585 320 240 1000\n", "width"},
  };
  for (const auto& [text, why] : bad) {
    try {
      rekon::parseIntrinsics(text, "cam.yaml");
      ADD_FAILURE() << "accepted: " << text;
    } catch (const rekon::Error& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.rfind("cam.yaml: ", 0), 0u) << what;
      EXPECT_NE(what.find(why), std::string::npos) << "'" << why << "' in: " << what;
      EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    }
  }
}

TEST(CameraYaml, OneLineFileLoadsThroughTheDataset) {
  rekon::test::TempDir dir;
  makeDataset(dir.path(), 2);
  std::ofstream(dir / "camera.yaml", std::ios::trunc) << "8 6 5 5 3.5 2.5 1000\n";
  rekon::TumDataset ds(dir.path());
  EXPECT_EQ(ds.intrinsics().width, 8);
  EXPECT_EQ(ds.intrinsics().depth_scale, 1000.0);
}
