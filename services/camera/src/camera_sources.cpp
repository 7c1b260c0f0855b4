#include <spdlog/spdlog.h>

#include "rekon/camera/source.hpp"
#include "rekon/common/error.hpp"

namespace rekon::camera {

namespace {
// The drivers this build has, and what to install for one it has not.
[[maybe_unused]] std::string missingDriver(const std::string& driver, const char* package) {
  return "rekon-camera was built without " + driver + " (Debian package " + package +
         " was missing at build time); install it and rebuild (tools/rekon setup)";
}
}  // namespace

std::unique_ptr<CameraSource> openCamera(const std::string& spec, const SourceOptions& options) {
  const size_t colon = spec.find(':');
  const std::string driver = spec.substr(0, colon);
  const std::string device = colon == std::string::npos ? "" : spec.substr(colon + 1);
  if (driver == "openni2") {
#ifdef REKON_HAVE_OPENNI2
    return openOpenNI2(device, options);
#else
    throw Error(missingDriver("OpenNI2", "libopenni2-dev"));
#endif
  }
  if (driver == "freenect") {
#ifdef REKON_HAVE_FREENECT
    return openFreenect(device, options);
#else
    throw Error(missingDriver("libfreenect", "libfreenect-dev"));
#endif
  }
  throw Error("camera '" + spec + "': unknown driver '" + driver +
              "'; use openni2[:URI] or freenect[:INDEX] (rekon cameras lists what is connected)");
}

std::vector<CameraInfo> listCameras() {
  std::vector<CameraInfo> all;
  auto add = [&](const char* driver, auto list) {
    try {
      for (auto& info : list()) all.push_back(std::move(info));
    } catch (const std::exception& e) {
      spdlog::warn("{}: {}", driver, e.what());
    }
  };
#ifdef REKON_HAVE_OPENNI2
  add("openni2", listOpenNI2);
#else
  spdlog::warn("{}", missingDriver("OpenNI2", "libopenni2-dev"));
#endif
#ifdef REKON_HAVE_FREENECT
  add("freenect", listFreenect);
#else
  spdlog::warn("{}", missingDriver("libfreenect", "libfreenect-dev"));
#endif
  return all;
}

}  // namespace rekon::camera
