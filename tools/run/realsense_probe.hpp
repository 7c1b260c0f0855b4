#pragma once
// What Intel's SDK sees, asked through rekon-realsense (services/realsense:
// Python, run with the project's .venv, where pyrealsense2 lives): `rekon
// cameras` lists RealSense cameras with it, and `rekon run --camera
// realsense` checks the camera or its --playback recording before anything
// starts.
#include <string>
#include <vector>

namespace rekon {

struct RealSenseListing {
  std::vector<std::string> cameras;  // one line each: "realsense:SERIAL  NAME  firmware F  USB U"
  std::string error;                 // why the SDK could not be asked (no .venv, no pyrealsense2), one line; "" if it was
};
// rekon-realsense --list, next to this executable.
RealSenseListing listRealSenseCameras();

// rekon-realsense --check ARGS (the camera, or a recording's depth, color and
// mode, resolved through the SDK, nothing started): "" when the source can be
// opened, else its one line saying why.
std::string whyRealSenseCannotOpen(const std::vector<std::string>& args);

}  // namespace rekon
