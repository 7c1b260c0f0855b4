// The built binaries on broken datasets and configs: each ends with exit
// status 1 and one error line naming the file (or key) and the fix, never a
// crash, a hang or decoder noise. (The library-level checks are in
// tests/common; these prove the message reaches the operator intact.)
#include "broken_dataset.hpp"

namespace rekon::hostile {
namespace {

TEST(BrokenInput, EmptyDatasetFolderNamesTheMissingIndex) {
  test::TempDir dir;
  fs::create_directories(dir / "empty");
  std::ofstream(dir / "empty/camera.yaml") << kCameraYaml;
  expectOneLineError(player("--dataset " + (dir / "empty")), {"rgb.txt"});
}

TEST(BrokenInput, DatasetWithoutFramesIsOneLine) {
  test::TempDir dir;
  makeDataset(dir / "d");
  std::ofstream(dir / "d/rgb.txt", std::ios::trunc) << "# no frames\n";
  expectOneLineError(player("--dataset " + (dir / "d")), {dir / "d"});
}

TEST(BrokenInput, NanFocalLengthNamesTheKey) {
  test::TempDir dir;
  makeDataset(dir / "d");
  std::ofstream(dir / "d/camera.yaml", std::ios::trunc) << "width: 160\nheight: 120\nfx: .nan\nfy: 120\ncx: 79.5\ncy: 59.5\ndepth_scale: 5000\n";
  expectOneLineError(player("--dataset " + (dir / "d")), {"camera.yaml", "fx"});
}

TEST(BrokenInput, InfiniteDepthScaleNamesTheKey) {
  test::TempDir dir;
  makeDataset(dir / "d");
  std::ofstream(dir / "d/camera.yaml", std::ios::trunc) << "width: 160\nheight: 120\nfx: 120\nfy: 120\ncx: 79.5\ncy: 59.5\ndepth_scale: .inf\n";
  expectOneLineError(player("--dataset " + (dir / "d")), {"camera.yaml", "depth_scale"});
}

TEST(BrokenInput, TruncatedDepthPngMidwayNamesTheFile) {
  test::TempDir dir;
  makeDataset(dir / "d");
  truncate(dir / "d/depth/2.png");
  expectOneLineError(player("--dataset " + (dir / "d")), {"depth/2.png", "truncated"});
}

TEST(BrokenInput, TruncatedJpegColorNamesTheFile) {
  test::TempDir dir;
  makeDataset(dir / "d", /*jpeg_color=*/true);
  truncate(dir / "d/rgb/1.jpg");
  expectOneLineError(player("--dataset " + (dir / "d")), {"rgb/1.jpg", "truncated"});
}

TEST(BrokenInput, EightBitDepthNamesTheBitDepth) {
  test::TempDir dir;
  makeDataset(dir / "d");
  writeImage(dir / "d/depth/3.png", cv::Mat(kHeight, kWidth, CV_8UC1, cv::Scalar(9)));
  expectOneLineError(player("--dataset " + (dir / "d")), {"depth/3.png", "16-bit"});
}

TEST(BrokenInput, ColorOfAnotherSizeNamesBothSizes) {
  test::TempDir dir;
  makeDataset(dir / "d");
  writeImage(dir / "d/rgb/1.png", cv::Mat(40, kWidth, CV_8UC3, cv::Scalar(1, 2, 3)));
  expectOneLineError(player("--dataset " + (dir / "d")), {"rgb/1.png", "160x40", "160x120"});
}

TEST(BrokenInput, InvalidYamlConfigNamesTheFile) {
  test::TempDir dir;
  makeDataset(dir / "d");
  std::ofstream(dir / "bad.yaml") << "tracker: [unclosed\n  finest_level: {\n";
  expectOneLineError(player("--dataset " + (dir / "d") + " --config " + (dir / "bad.yaml")), {"bad.yaml"});
}

TEST(BrokenInput, UnknownConfigKeyIsNamed) {
  test::TempDir dir;
  makeDataset(dir / "d");
  std::ofstream(dir / "typo.yaml") << "tracker:\n  finest_levle: 1\n";
  expectOneLineError(player("--dataset " + (dir / "d") + " --config " + (dir / "typo.yaml")), {"tracker.finest_levle"});
}

TEST(BrokenInput, CameraYamlAsAListNamesTheFileAndTheForms) {
  test::TempDir dir;
  makeDataset(dir / "d");
  std::ofstream(dir / "d/camera.yaml", std::ios::trunc) << "- 160\n- 120\n";
  expectOneLineError(player("--dataset " + (dir / "d")), {"camera.yaml", "seven numbers on one line"});
}

TEST(BrokenInput, OneLineCameraYamlPlays) {
  test::TempDir dir;
  makeDataset(dir / "d");
  std::ofstream(dir / "d/camera.yaml", std::ios::trunc) << "160 120 120 120 79.5 59.5 5000\n";
  const Outcome o = player("--dataset " + (dir / "d"));
  EXPECT_EQ(o.status, 0) << o.output;
  EXPECT_EQ(test::crashLines(o.output), "");
}

// create_directories threw std::filesystem_error past the rekon::Error handler: std::terminate.
TEST(BrokenInput, UnwritableOutputFolderIsOneLine) {
  test::TempDir dir;
  makeDataset(dir / "d");
  std::ofstream(dir / "file") << "in the way\n";
  expectOneLineError(player("--dataset " + (dir / "d") + " --out " + (dir / "file/out")), {"file/out", "--out"});
}

}  // namespace
}  // namespace rekon::hostile
