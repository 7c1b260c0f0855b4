#pragma once
// Broken datasets and how the binaries must fail on them (tests/hostile).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "rekon/common/image_io.hpp"
#include "test_support.hpp"

namespace rekon::hostile {
namespace fs = std::filesystem;

// Large enough for the tracker's pyramid (levels 1..3 need 8x8 at the coarsest).
inline constexpr int kWidth = 160, kHeight = 120, kFrames = 4;

inline const std::string kCameraYaml = "width: 160\nheight: 120\nfx: 120\nfy: 120\ncx: 79.5\ncy: 59.5\ndepth_scale: 5000\n";

// A valid TUM dataset of kFrames small frames; color as PNG or JPEG.
inline void makeDataset(const std::string& dir, bool jpeg_color = false) {
  fs::create_directories(dir + "/rgb");
  fs::create_directories(dir + "/depth");
  std::ofstream(dir + "/camera.yaml") << kCameraYaml;
  std::ofstream rgb(dir + "/rgb.txt"), depth(dir + "/depth.txt");
  for (int i = 0; i < kFrames; ++i) {
    cv::Mat color(kHeight, kWidth, CV_8UC3), d(kHeight, kWidth, CV_16UC1);
    cv::randu(color, 0, 255);
    cv::randu(d, 2000, 8000);
    const std::string c = "rgb/" + std::to_string(i) + (jpeg_color ? ".jpg" : ".png");
    const std::string z = "depth/" + std::to_string(i) + ".png";
    writeImage(dir + "/" + c, color);
    writeImage(dir + "/" + z, d);
    rgb << i / 30.0 << " " << c << "\n";
    depth << i / 30.0 << " " << z << "\n";
  }
}

inline void truncate(const std::string& path) {
  const auto size = fs::file_size(path);
  fs::resize_file(path, size * 2 / 3);
}

struct Outcome {
  int status = 0;
  std::string output;
};

// rekon-player alone (nobody to wait for), in a private network namespace, with a time limit.
inline Outcome player(const std::string& args) {
  Outcome o;
  o.status = test::runCommand(test::sourceDir() + "/tests/support/in_netns.sh timeout -k 5 60 " + test::binDir() +
                                  "/rekon-player --set 'player.wait_for=[]' " + args,
                              &o.output);
  return o;
}

inline std::vector<std::string> errorLines(const std::string& output) {
  std::vector<std::string> lines;
  std::istringstream in(output);
  std::string line;
  while (std::getline(in, line)) {
    if (line.find("error") != std::string::npos) lines.push_back(line);
  }
  return lines;
}

// Exit status 1, exactly one error line, containing every one of `names`, no crash signs.
inline void expectOneLineError(const Outcome& o, const std::vector<std::string>& names) {
  EXPECT_EQ(o.status, 1) << o.output;
  const auto lines = errorLines(o.output);
  ASSERT_EQ(lines.size(), 1u) << o.output;
  for (const auto& name : names) EXPECT_NE(lines[0].find(name), std::string::npos) << "'" << name << "' in: " << lines[0];
  EXPECT_EQ(test::crashLines(o.output), "");
}

}  // namespace rekon::hostile
