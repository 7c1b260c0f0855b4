// freenect_probe --out DIR [--calibration FILE] [--index 0] | --list: opens a Kinect
// through openFreenect and takes every frame until the source ends, is
// lost, or --max-frames; writes depth/NNNNNN.png (mm), rgb/NNNNNN.png and
// frames.txt ("index timestamp"), and prints what happened. The freenect
// tests run it as a child process so that the fakenect library
// (LD_LIBRARY_PATH) is loaded into it and not into the test.
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <thread>
#include <vector>

#include "rekon/camera/source.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"

namespace {

const char* statusName(rekon::camera::Capture::Status s) {
  switch (s) {
    case rekon::camera::Capture::Status::kFrame: return "frame";
    case rekon::camera::Capture::Status::kTimeout: return "timeout";
    case rekon::camera::Capture::Status::kEnded: return "ended";
    case rekon::camera::Capture::Status::kLost: return "lost";
  }
  return "?";
}

void writeFrames(const std::vector<rekon::RgbdFrame>& frames, const std::string& out) {
  rekon::createOutputFolder(out + "/depth");
  rekon::createOutputFolder(out + "/rgb");
  std::ofstream index(out + "/frames.txt");
  const std::vector<int> fast = {cv::IMWRITE_PNG_COMPRESSION, 1};
  for (size_t i = 0; i < frames.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "%06zu.png", i);
    cv::imwrite(out + "/depth/" + name, frames[i].depth, fast);
    cv::imwrite(out + "/rgb/" + name, frames[i].color, fast);
    index.precision(17);
    index << i << " " << frames[i].timestamp << "\n";
  }
}

}  // namespace

int main(int argc, char** argv) {
  try {
    rekon::ArgParser args(argv[0], "Take every frame of a camera (test helper).");
    args.option("out", "folder for the frames")
        .option("index", "device index", "0")
        .option("calibration", "camera.yaml", "")
        .option("max-frames", "stop after this many (0 = no limit)", "0")
        .option("give-up", "seconds without a frame before giving up", "20")
        .option("consume-every", "seconds to sleep after each frame (a slow consumer)", "0")
        .flag("list", "print what listFreenect sees (camera=URI|NAME|SERIAL|MODE;MODE...) instead");
    if (!args.parse(argc, argv)) return 0;
    if (args.flagSet("list")) {
      for (const auto& info : rekon::camera::listFreenect()) {
        std::string modes;
        for (const auto& mode : info.modes) modes += (modes.empty() ? "" : ";") + mode;
        std::printf("camera=%s|%s|%s|%s\n", info.uri.c_str(), info.name.c_str(), info.serial.c_str(), modes.c_str());
      }
      return 0;
    }
    rekon::camera::SourceOptions options;
    if (!args.get("calibration").empty()) options.calibration_file = args.get("calibration");
    const auto source = rekon::camera::openFreenect(args.get("index"), options);
    const rekon::Intrinsics k = source->intrinsics();
    std::printf("describe=%s\nintrinsics=%d %d %.3f %.3f %.3f %.3f %.1f\n", source->describe().c_str(), k.width,
                k.height, k.fx, k.fy, k.cx, k.cy, k.depth_scale);
    std::vector<rekon::RgbdFrame> frames;
    const int max_frames = args.getInt("max-frames");
    const double give_up = args.getDouble("give-up");
    const double consume_every = args.getDouble("consume-every");
    rekon::camera::Capture capture;
    double waited = 0.0;
    while (waited < give_up && (max_frames == 0 || static_cast<int>(frames.size()) < max_frames)) {
      capture = source->next(0.5);
      if (capture.status == rekon::camera::Capture::Status::kFrame) {
        frames.push_back(capture.frame);
        waited = 0.0;
        std::this_thread::sleep_for(std::chrono::duration<double>(consume_every));
      } else if (capture.status == rekon::camera::Capture::Status::kTimeout) {
        waited += 0.5;
      } else {
        break;
      }
    }
    writeFrames(frames, args.get("out"));
    std::printf("status=%s\nframes=%zu\nreplaced=%lld\nreason=%s\n", statusName(capture.status), frames.size(),
                static_cast<long long>(source->framesReplaced()), capture.reason.c_str());
  } catch (...) {
    std::printf("error=%s\n", rekon::currentExceptionLine().c_str());
    return 3;
  }
  return 0;
}
