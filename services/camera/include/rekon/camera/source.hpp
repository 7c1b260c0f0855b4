#pragma once
// A live RGB-D camera as rekon-camera sees it: a driver (OpenNI2 or
// libfreenect) opened by a device spec, giving registered frames (depth in
// millimetres aligned to the color image, color BGR) stamped with the host's
// clock at capture. Drivers are behind this one interface so the capture loop,
// pacing and recording do not know which one runs.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/rgbd_frame.hpp"

namespace rekon::camera {

// What `rekon cameras` prints for one connected device.
struct CameraInfo {
  std::string driver;  // "openni2" | "freenect"
  std::string uri;     // what --camera DRIVER:URI takes (OpenNI2 URI, freenect index)
  std::string name;    // vendor and model, as the driver reports them
  std::string serial;  // "" when the driver does not report one
  std::vector<std::string> modes;  // e.g. "depth 640x480@30 registered", "color 640x480@30 rgb"
};

// How to open a device.
struct SourceOptions {
  // Calibration from --calibration FILE (camera.yaml, see kinect_depth.hpp for
  // the optional depth-camera keys); nullopt = what the device reports, else
  // the driver's nominal values with a warning.
  std::optional<std::string> calibration_file;
  int width = 640;
  int height = 480;
  int fps = 30;
  // camera.clock: false stamps frames with this computer's clock at capture
  // (a live scan); true with a recording's own clock (the times a fakenect
  // recording or an .oni file holds), so that a recording made from a
  // dataset can be scored against the dataset's ground truth.
  bool recording_clock = false;
};

// One call of CameraSource::next.
struct Capture {
  enum class Status {
    kFrame,    // `frame` holds a new registered frame
    kTimeout,  // nothing within the timeout; call again
    kEnded,    // a recording reached its end (clean end of stream)
    kLost,     // the device vanished or failed: `reason` is one line naming it and the fix
  };
  Status status = Status::kTimeout;
  RgbdFrame frame;  // depth CV_16UC1 in units of intrinsics().depth_scale; color CV_8UC3 BGR; timestamp: see SourceOptions::recording_clock
  double host_time = 0.0;  // this computer's wall-clock seconds at capture, whichever clock `frame.timestamp` is on
  std::string reason;
};

class CameraSource {
 public:
  virtual ~CameraSource() = default;
  // Waits up to `timeout_s` for the next frame. Never throws for a device
  // that vanishes mid-run (that is Status::kLost); frame ids are left to the
  // caller.
  virtual Capture next(double timeout_s) = 0;
  // The intrinsics of the registered frames (of the color camera).
  virtual Intrinsics intrinsics() const = 0;
  // One line for the log: driver, device, mode, registration in use.
  virtual std::string describe() const = 0;
  // Frames the device delivered that a newer one replaced before next()
  // took them (a driver keeps only the newest; the capture loop was late):
  // the camera's frames_skipped_late.
  virtual int64_t framesReplaced() const { return 0; }
};

// Opens "openni2[:URI]" or "freenect[:INDEX]" (no URI/index: the first
// device). Throws rekon::Error with one line naming the device and what to do
// when there is no such device, it is busy, or the driver is not built in.
std::unique_ptr<CameraSource> openCamera(const std::string& spec, const SourceOptions& options);

// Every device the built-in drivers can see; never throws (a driver that
// fails to initialise is logged and skipped).
std::vector<CameraInfo> listCameras();

// Per driver (each in its own source file; declared here so openCamera and
// listCameras stay in one place).
std::unique_ptr<CameraSource> openOpenNI2(const std::string& uri, const SourceOptions& options);
std::vector<CameraInfo> listOpenNI2();
std::unique_ptr<CameraSource> openFreenect(const std::string& index, const SourceOptions& options);
std::vector<CameraInfo> listFreenect();

}  // namespace rekon::camera
