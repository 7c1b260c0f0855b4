// `rekon cameras`: the RGB-D cameras the built-in drivers can see.
#include <cstdio>

#include "commands.hpp"
#include "rekon/camera/source.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/logging.hpp"

namespace rekon {

int camerasCommand(int argc, char** argv) {
  ArgParser args("rekon cameras", "Lists the RGB-D cameras that OpenNI2 and libfreenect can see, with their modes.");
  if (!args.parse(argc, argv)) return 0;
  setupLogging("cameras", "warn");
  const auto cameras = camera::listCameras();
  if (cameras.empty()) {
    std::printf("no camera found; plug one in (and see README \"Live camera\" for the udev rules), "
                "or replay a recording: openni2:FILE.oni, or freenect with FAKENECT_PATH\n");
    return 1;
  }
  for (const auto& c : cameras) {
    std::printf("%s:%s  %s%s%s\n", c.driver.c_str(), c.uri.c_str(), c.name.c_str(), c.serial.empty() ? "" : "  serial ",
                c.serial.c_str());
    for (const auto& m : c.modes) std::printf("    %s\n", m.c_str());
  }
  return 0;
}

}  // namespace rekon
