// `rekon cameras`: the RGB-D cameras the built-in drivers and Intel's RealSense SDK can see.
#include <cstdio>

#include "commands.hpp"
#include "realsense_probe.hpp"
#include "rekon/camera/source.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/logging.hpp"

namespace rekon {

int camerasCommand(int argc, char** argv) {
  ArgParser args("rekon cameras", "Lists the RGB-D cameras that OpenNI2 and libfreenect can see, with their modes, "
                                  "and the Intel RealSense cameras that Intel's SDK (pyrealsense2 in .venv) sees.");
  if (!args.parse(argc, argv)) return 0;
  setupLogging("cameras", "warn");
  const auto cameras = camera::listCameras();
  for (const auto& c : cameras) {
    std::printf("%s:%s  %s%s%s\n", c.driver.c_str(), c.uri.c_str(), c.name.c_str(), c.serial.empty() ? "" : "  serial ",
                c.serial.c_str());
    for (const auto& m : c.modes) std::printf("    %s\n", m.c_str());
  }
  const RealSenseListing realsense = listRealSenseCameras();
  for (const auto& line : realsense.cameras) std::printf("%s\n", line.c_str());
  if (!realsense.error.empty()) std::printf("RealSense cameras not listed: %s\n", realsense.error.c_str());
  if (cameras.empty() && realsense.cameras.empty()) {
    std::printf("no camera found; plug one in (and see docs/cameras.md for the udev rules), or replay a recording: "
                "openni2:FILE.oni, freenect with FAKENECT_PATH, realsense --playback FILE.bag\n");
    return 1;
  }
  return 0;
}

}  // namespace rekon
