// The OpenNI2 driver: Kinect v1 / Asus Xtion / PrimeSense devices through
// OpenNI2's own drivers (PS1080, PSLink), and .oni recordings through its
// file device (OniFile). Depth and color are separate streams read with
// waitForAnyStream and paired here; depth is registered to color by the
// device when it can, else in software from a calibration with depth-camera
// keys (kinect_depth.hpp), else passed on unregistered with a warning.
#include <OpenNI.h>
#include <spdlog/spdlog.h>

#include <opencv2/core.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <deque>
#include <filesystem>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

#include "rekon/camera/device_clock.hpp"
#include "rekon/camera/kinect_depth.hpp"
#include "rekon/camera/source.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/threads.hpp"

namespace rekon::camera {

namespace {

// A device (or file) that sent nothing for this long is gone: a live camera
// streams at 30 Hz, and OpenNI2 does not report every unplugged device.
constexpr double kLostAfterS = 5.0;
// One waitForAnyStream; bounds how late a disconnect or end of file is seen.
constexpr int kWaitSliceMs = 100;
// Depth and color are paired by frame index from the last few frames of each
// (one stream may run a frame or two ahead: DummyDevice raises color a frame
// period after depth); after this many frames without a match the device
// numbers them independently and the newest of each is paired.
constexpr size_t kPairWindow = 3;
constexpr int kMaxIndexMismatches = 30;
// DummyDevice's generator thread outlives stop() and raises one more frame
// into the stream: destroying the stream earlier crashes, so the threads the
// streams' start() started are waited for (rekon/common/threads.hpp), this
// long at most. And its thread sets its own running flag when it starts, so a
// stop() before that is lost: a stream is stopped only after its first frame
// (or this long).
constexpr auto kDriverThreadsEnd = std::chrono::milliseconds(2000);
constexpr int kFirstFrameBeforeStopMs = 1000;
// A Kinect v1 color camera, when a device reports no field of view: fx = fy
// = 525 at 640x480 (TUM's and ROS's nominal value), scaled with the width.
constexpr double kNominalFx640 = 525.0;

const char* const kOpenHint =
    "rekon cameras lists the devices OpenNI2 sees; a device missing there needs Debian's udev rules "
    "(/lib/udev/rules.d/60-libopenni2-0.rules, then replug) and a user in group video (the group those rules give); a busy one is "
    "open in another program";

// OpenNI2's extended error folded to one line.
std::string oniError() {
  std::string text = openni::OpenNI::getExtendedError();
  for (char& c : text)
    if (c == '\n' || c == '\r' || c == '\t') c = ' ';
  text.erase(std::unique(text.begin(), text.end(), [](char a, char b) { return a == ' ' && b == ' '; }), text.end());
  while (!text.empty() && text.back() == ' ') text.pop_back();
  while (!text.empty() && text.front() == ' ') text.erase(text.begin());
  return text.empty() ? "no detail from OpenNI2" : text;
}

bool isOniFile(const std::string& uri) {
  return uri.size() > 4 && uri.compare(uri.size() - 4, 4, ".oni") == 0;
}

// OpenNI::initialize/shutdown count calls: one of these per user keeps the
// drivers loaded exactly while a source or a listing needs them.
class OpenNIScope {
 public:
  OpenNIScope() {
    std::lock_guard<std::mutex> lock(mutex());
    if (openni::OpenNI::initialize() != openni::STATUS_OK)
      throw Error("OpenNI2 failed to initialise: " + oniError() + "; check /etc/openni2/OpenNI.ini and " +
                  "that libopenni2-0's drivers are in /usr/lib/x86_64-linux-gnu/OpenNI2/Drivers");
  }
  ~OpenNIScope() {
    std::lock_guard<std::mutex> lock(mutex());
    openni::OpenNI::shutdown();
  }
  OpenNIScope(const OpenNIScope&) = delete;
  OpenNIScope& operator=(const OpenNIScope&) = delete;

 private:
  static std::mutex& mutex() {
    static std::mutex m;
    return m;
  }
};

std::string pixelFormatName(openni::PixelFormat format) {
  switch (format) {
    case openni::PIXEL_FORMAT_DEPTH_1_MM: return "1mm";
    case openni::PIXEL_FORMAT_DEPTH_100_UM: return "100um";
    case openni::PIXEL_FORMAT_SHIFT_9_2: return "shift9.2";
    case openni::PIXEL_FORMAT_SHIFT_9_3: return "shift9.3";
    case openni::PIXEL_FORMAT_RGB888: return "rgb";
    case openni::PIXEL_FORMAT_YUV422: return "yuv422";
    case openni::PIXEL_FORMAT_YUYV: return "yuyv";
    case openni::PIXEL_FORMAT_GRAY8: return "gray8";
    case openni::PIXEL_FORMAT_GRAY16: return "gray16";
    case openni::PIXEL_FORMAT_JPEG: return "jpeg";
    default: return "format" + std::to_string(static_cast<int>(format));
  }
}

std::string modeText(const openni::VideoMode& mode) {
  return std::to_string(mode.getResolutionX()) + "x" + std::to_string(mode.getResolutionY()) + "@" +
         std::to_string(mode.getFps()) + " " + pixelFormatName(mode.getPixelFormat());
}

// The offered mode of `format` nearest to the asked size and rate (size
// first: a wrong size is a different camera model, a wrong rate only pacing).
std::optional<openni::VideoMode> closestMode(const openni::SensorInfo* sensor, openni::PixelFormat format,
                                             const SourceOptions& options) {
  std::optional<openni::VideoMode> best;
  double best_cost = 0.0;
  const auto& modes = sensor->getSupportedVideoModes();
  for (int i = 0; i < modes.getSize(); ++i) {
    if (modes[i].getPixelFormat() != format) continue;
    const double cost = 1000.0 * (std::abs(modes[i].getResolutionX() - options.width) +
                                  std::abs(modes[i].getResolutionY() - options.height)) +
                        std::abs(modes[i].getFps() - options.fps);
    if (!best || cost < best_cost) best = modes[i], best_cost = cost;
  }
  return best;
}

// A device (or a file) going away, and a file reaching its end: OpenNI2
// reports both on its own thread.
class DeviceEvents : public openni::OpenNI::DeviceDisconnectedListener,
                     public openni::OpenNI::DeviceStateChangedListener {
 public:
  explicit DeviceEvents(std::string uri) : uri_(std::move(uri)) {
    openni::OpenNI::addDeviceDisconnectedListener(this);
    openni::OpenNI::addDeviceStateChangedListener(this);
  }
  ~DeviceEvents() override {
    openni::OpenNI::removeDeviceDisconnectedListener(this);
    openni::OpenNI::removeDeviceStateChangedListener(this);
  }
  void onDeviceDisconnected(const openni::DeviceInfo* info) override {
    if (uri_ == info->getUri()) disconnected = true;
  }
  void onDeviceStateChanged(const openni::DeviceInfo* info, openni::DeviceState state) override {
    if (uri_ != info->getUri()) return;
    if (state == openni::DEVICE_STATE_EOF) ended = true;
    if (state == openni::DEVICE_STATE_ERROR) failed = true;
  }
  std::atomic<bool> disconnected{false}, ended{false}, failed{false};

 private:
  std::string uri_;
};

class OpenNI2Source : public CameraSource {
 public:
  OpenNI2Source(const std::string& uri, const SourceOptions& options);
  ~OpenNI2Source() override;
  Capture next(double timeout_s) override;
  Intrinsics intrinsics() const override { return intrinsics_; }
  std::string describe() const override { return description_; }
  int64_t framesReplaced() const override { return replaced_; }

 private:
  void openDevice();
  void createStreams(const SourceOptions& options);
  void chooseMode(openni::VideoStream& stream, openni::SensorType sensor, openni::PixelFormat format,
                  const SourceOptions& options);
  void setUpRegistration(const SourceOptions& options);
  void setUpIntrinsics(const SourceOptions& options);
  void startStreams();
  std::optional<Capture> readReady(int stream);
  bool takePair(openni::VideoFrameRef& depth, openni::VideoFrameRef& color);
  Capture makeFrame(const openni::VideoFrameRef& depth, const openni::VideoFrameRef& color);
  std::optional<Capture> checkQuiet();
  Capture finish(Capture::Status status, const std::string& reason);

  std::string uri_;
  OpenNIScope scope_;
  openni::Device device_;
  openni::VideoStream streams_[2];  // depth, color
  std::set<int> device_threads_;    // the threads the device's open() started
  std::set<int> stream_threads_;    // the threads the streams' start() started
  std::unique_ptr<DeviceEvents> events_;
  bool is_file_ = false;
  bool recording_clock_ = false;
  std::optional<DepthWarp> software_registration_;
  Intrinsics intrinsics_;
  std::string intrinsics_source_, registration_text_, description_;

  std::deque<openni::VideoFrameRef> recent_[2];  // unpaired frames, oldest first
  bool streamed_[2] = {false, false};  // a frame has arrived (see kFirstFrameBeforeStopMs)
  bool pair_by_index_ = true;
  int mismatches_ = 0;
  long long frames_ = 0;
  // Depth frames the device numbered between two taken ones: replaced in the
  // driver (it keeps the newest) or dropped unpaired here.
  int last_depth_index_ = 0;
  int64_t replaced_ = 0;
  DeviceClock clock_;  // device timestamps onto the host clock
  std::chrono::steady_clock::time_point last_frame_;
  std::optional<Capture> finished_;
};

OpenNI2Source::OpenNI2Source(const std::string& uri, const SourceOptions& options)
    : uri_(uri), recording_clock_(options.recording_clock) {
  if (recording_clock_ && !isOniFile(uri_))
    throw Error("OpenNI2 device '" + uri_ + "': camera.clock is 'recording' but a live device has only this computer's "
                "clock; set camera.clock=host (or play an .oni file)");
  openDevice();
  createStreams(options);
  setUpRegistration(options);
  setUpIntrinsics(options);
  startStreams();
  const openni::VideoMode depth = streams_[0].getVideoMode(), color = streams_[1].getVideoMode();
  description_ = "openni2 '" + uri_ + "' (" + device_.getDeviceInfo().getVendor() + " " +
                 device_.getDeviceInfo().getName() + "): depth " + modeText(depth) + ", color " + modeText(color) +
                 ", " + registration_text_ + ", intrinsics " + intrinsics_source_;
  spdlog::info("{}", description_);
}

OpenNI2Source::~OpenNI2Source() {
  for (int i = 0; i < 2; ++i) {
    if (streamed_[i] || !streams_[i].isValid()) continue;
    openni::VideoStream* stream = &streams_[i];
    int ready = -1;
    openni::OpenNI::waitForAnyStream(&stream, 1, &ready, kFirstFrameBeforeStopMs);
  }
  for (auto& stream : streams_) stream.stop();
  if (!waitForThreadsToEnd(stream_threads_, kDriverThreadsEnd))
    spdlog::warn("OpenNI2 device '{}': the driver's stream threads still run {} ms after stop", uri_,
                 kDriverThreadsEnd.count());
  for (auto& recent : recent_) recent.clear();
  // OniFile's player thread walks its list of streams without a lock, and
  // sleeps 10 ms between walks once no stream runs: a stream destroyed during
  // a walk is read after it was freed (a segfault in 1 % of the sources, four
  // test processes at once). Each stream is destroyed the moment it sleeps.
  for (auto& stream : streams_) {
    waitForThreadsToBlock(device_threads_, kDriverThreadsEnd);
    stream.destroy();
  }
  events_.reset();
  device_.close();
}

void OpenNI2Source::openDevice() {
  is_file_ = isOniFile(uri_);
  const std::string shown = uri_.empty() ? "the first OpenNI2 device" : "OpenNI2 device '" + uri_ + "'";
  if (is_file_ && !std::filesystem::is_regular_file(uri_))
    throw Error("OpenNI2 recording '" + uri_ + "' does not exist; check the path after openni2:");
  openni::Status opened = openni::STATUS_OK;
  device_threads_ =
      threadsStartedBy([&] { opened = device_.open(uri_.empty() ? openni::ANY_DEVICE : uri_.c_str()); });
  // A file device closed before its thread first ran loses the close (rekon/common/threads.hpp).
  waitForThreadsToBlock(device_threads_, kDriverThreadsEnd);
  if (opened != openni::STATUS_OK) {
    const std::string hint = is_file_ ? "check that it is a complete .oni recording (OpenNI2 opens no truncated "
                                        "one; rekon-oni-record makes one)"
                                      : kOpenHint;
    throw Error("cannot open " + shown + ": " + oniError() + "; " + hint);
  }
  if (uri_.empty()) uri_ = device_.getDeviceInfo().getUri();
  events_ = std::make_unique<DeviceEvents>(device_.getDeviceInfo().getUri());
  if (is_file_) {
    // A live camera cannot wait for its reader: the file plays at its recorded
    // rate, once (OniFile loops by default).
    openni::PlaybackControl* playback = device_.getPlaybackControl();
    if (playback->setRepeatEnabled(false) != openni::STATUS_OK || playback->setSpeed(1.0f) != openni::STATUS_OK)
      throw Error("OpenNI2 recording '" + uri_ + "': cannot set its playback (" + oniError() + ")");
  }
}

void OpenNI2Source::createStreams(const SourceOptions& options) {
  if (streams_[0].create(device_, openni::SENSOR_DEPTH) != openni::STATUS_OK)
    throw Error("OpenNI2 device '" + uri_ + "' has no depth stream: " + oniError());
  if (streams_[1].create(device_, openni::SENSOR_COLOR) != openni::STATUS_OK)
    throw Error("OpenNI2 device '" + uri_ + "' has no color stream: " + oniError());
  chooseMode(streams_[0], openni::SENSOR_DEPTH, openni::PIXEL_FORMAT_DEPTH_1_MM, options);
  chooseMode(streams_[1], openni::SENSOR_COLOR, openni::PIXEL_FORMAT_RGB888, options);
  for (auto& stream : streams_) {
    // Not every device can mirror (or un-mirror); what it sends then is what it has.
    if (stream.isPropertySupported(openni::STREAM_PROPERTY_MIRRORING)) stream.setMirroringEnabled(false);
  }
  const openni::VideoMode depth = streams_[0].getVideoMode(), color = streams_[1].getVideoMode();
  if (depth.getPixelFormat() != openni::PIXEL_FORMAT_DEPTH_1_MM ||
      color.getPixelFormat() != openni::PIXEL_FORMAT_RGB888)
    throw Error("OpenNI2 device '" + uri_ + "' streams depth " + modeText(depth) + " and color " + modeText(color) +
                "; rekon needs depth in 1 mm units and RGB888 color (rekon cameras lists the modes)");
}

// The recorded mode of a file cannot be changed (OniFile refuses), so a file
// keeps its own; a device gets the closest mode it offers.
void OpenNI2Source::chooseMode(openni::VideoStream& stream, openni::SensorType sensor, openni::PixelFormat format,
                               const SourceOptions& options) {
  const char* name = sensor == openni::SENSOR_DEPTH ? "depth" : "color";
  const std::optional<openni::VideoMode> mode = closestMode(&stream.getSensorInfo(), format, options);
  if (is_file_ || !mode) {
    spdlog::info("openni2 '{}': {} {} (the {}'s own mode)", uri_, name, modeText(stream.getVideoMode()),
                 is_file_ ? "recording" : "device");
    return;
  }
  const openni::VideoMode current = stream.getVideoMode();
  const bool same = mode->getResolutionX() == current.getResolutionX() &&
                    mode->getResolutionY() == current.getResolutionY() && mode->getFps() == current.getFps() &&
                    mode->getPixelFormat() == current.getPixelFormat();
  // Some drivers (DummyDevice) refuse any mode change, even to the mode they run.
  if (!same && stream.setVideoMode(*mode) != openni::STATUS_OK) {
    spdlog::warn("openni2 '{}' refused {} mode {} ({}): keeping {}", uri_, name, modeText(*mode), oniError(),
                 modeText(current));
    return;
  }
  const bool exact = mode->getResolutionX() == options.width && mode->getResolutionY() == options.height &&
                     mode->getFps() == options.fps;
  spdlog::info("openni2 '{}': {} {}{}", uri_, name, modeText(*mode),
               exact ? "" : " (closest offered to " + std::to_string(options.width) + "x" +
                                std::to_string(options.height) + "@" + std::to_string(options.fps) + ")");
}

void OpenNI2Source::setUpRegistration(const SourceOptions& options) {
  if (!is_file_ && device_.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR) &&
      device_.setImageRegistrationMode(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR) == openni::STATUS_OK) {
    registration_text_ = "depth registered to color by the device";
    return;
  }
  if (options.calibration_file) {
    const KinectCalibration calibration = loadKinectCalibration(*options.calibration_file);
    const openni::VideoMode depth = streams_[0].getVideoMode();
    if (!calibration.aligned) {
      if (calibration.depth.width != depth.getResolutionX() || calibration.depth.height != depth.getResolutionY())
        throw Error(*options.calibration_file + " calibrates a " + std::to_string(calibration.depth.width) + "x" +
                    std::to_string(calibration.depth.height) + " depth camera but '" + uri_ + "' streams depth " +
                    modeText(depth) + "; pass --width/--height to match or a calibration of this mode");
      software_registration_.emplace(calibration.depth, calibration.color, calibration.depth_to_color_rotation,
                                     calibration.depth_to_color_translation);
      registration_text_ = "depth registered to color in software from " + *options.calibration_file;
      return;
    }
  }
  if (is_file_) {
    // The Recorder keeps stream properties only: whether the device registered
    // the depth it recorded is not in the file.
    registration_text_ = "depth registered as recorded";
    spdlog::info("openni2 '{}': depth is used as recorded (an .oni does not say whether the device registered it; "
                 "--calibration with depth-camera keys registers it in software)",
                 uri_);
    return;
  }
  registration_text_ = "depth NOT registered to color";
  spdlog::warn("openni2 '{}': the device offers no depth-to-color registration and no calibration with depth_camera "
               "keys was given: depth stays in the depth camera's geometry (pass --calibration camera.yaml with "
               "the depth-camera keys of kinect_depth.hpp to register it in software)",
               uri_);
}

void OpenNI2Source::setUpIntrinsics(const SourceOptions& options) {
  const openni::VideoMode color = streams_[1].getVideoMode();
  const int w = color.getResolutionX(), h = color.getResolutionY();
  if (options.calibration_file) {
    intrinsics_ = loadKinectCalibration(*options.calibration_file).color;
    if (intrinsics_.width != w || intrinsics_.height != h)
      throw Error(*options.calibration_file + " is for " + std::to_string(intrinsics_.width) + "x" +
                  std::to_string(intrinsics_.height) + " but '" + uri_ + "' streams color " + modeText(color) +
                  "; pass --width/--height to match or a calibration of this mode");
    intrinsics_source_ = "from " + *options.calibration_file;
  } else {
    intrinsics_.width = w;
    intrinsics_.height = h;
    const double hfov = streams_[1].getHorizontalFieldOfView(), vfov = streams_[1].getVerticalFieldOfView();
    const bool reported = std::isfinite(hfov) && std::isfinite(vfov) && hfov > 0.0 && vfov > 0.0;
    intrinsics_.fx = reported ? w / (2.0 * std::tan(hfov / 2.0)) : kNominalFx640 * w / 640.0;
    intrinsics_.fy = reported ? h / (2.0 * std::tan(vfov / 2.0)) : intrinsics_.fx;
    intrinsics_.cx = w / 2.0 - 0.5;
    intrinsics_.cy = h / 2.0 - 0.5;
    intrinsics_source_ = reported ? "from the color stream's field of view" : "nominal (Kinect v1 fx = 525 at 640 px)";
    if (!reported)
      spdlog::warn("openni2 '{}' reports no field of view: nominal intrinsics fx = fy = {:.1f}; pass --calibration "
                   "camera.yaml for a calibrated camera",
                   uri_, intrinsics_.fx);
  }
  intrinsics_.depth_scale = 1000.0;  // the frames are always in millimetres
  intrinsics_.validate("openni2 '" + uri_ + "'");
  spdlog::info("openni2 '{}': intrinsics {} (fx {:.2f} fy {:.2f} cx {:.2f} cy {:.2f})", uri_, intrinsics_source_,
               intrinsics_.fx, intrinsics_.fy, intrinsics_.cx, intrinsics_.cy);
}

void OpenNI2Source::startStreams() {
  stream_threads_ = threadsStartedBy([&] {
    for (auto& stream : streams_)
      if (stream.start() != openni::STATUS_OK)
        throw Error("OpenNI2 device '" + uri_ + "': cannot start streaming: " + oniError() + "; " + kOpenHint);
  });
  // Hardware sync must be asked for once both streams run (OpenNI2 syncs only
  // started streams); devices without it are paired by frame index here.
  const bool synced = device_.setDepthColorSyncEnabled(true) == openni::STATUS_OK;
  spdlog::info("openni2 '{}': depth/color sync {}", uri_,
               synced ? "by the device" : "not offered by the driver: paired by frame index");
  last_frame_ = std::chrono::steady_clock::now();
}

Capture OpenNI2Source::next(double timeout_s) {
  if (finished_) return *finished_;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(std::max(0.0, timeout_s));
  while (true) {
    if (events_->disconnected || events_->failed)
      return finish(Capture::Status::kLost, "OpenNI2 device '" + uri_ + "' was disconnected" +
                                                (events_->failed ? " (device error)" : "") +
                                                "; check its USB cable and power, then start again");
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    const int slice = static_cast<int>(std::clamp<long long>(left.count(), 0, kWaitSliceMs));
    openni::VideoStream* both[2] = {&streams_[0], &streams_[1]};
    int ready = -1;
    const openni::Status status = openni::OpenNI::waitForAnyStream(both, 2, &ready, slice);
    if (status == openni::STATUS_OK) {
      if (auto capture = readReady(ready)) return *capture;
      continue;
    }
    if (status != openni::STATUS_TIME_OUT)
      return finish(Capture::Status::kLost, "OpenNI2 device '" + uri_ + "' failed while waiting for frames: " +
                                                oniError() + "; check its USB cable and power, then start again");
    if (auto quiet = checkQuiet()) return *quiet;
    if (std::chrono::steady_clock::now() >= deadline) return Capture{};
  }
}

// Nothing arrived within one slice: the end of a file (OniFile has delivered
// every frame before it reports its end), or a device that stopped streaming.
std::optional<Capture> OpenNI2Source::checkQuiet() {
  if (events_->ended) {
    if (frames_ == 0)
      return finish(Capture::Status::kLost,
                    "OpenNI2 recording '" + uri_ + "' ended without one depth+color frame; a recording of OpenNI2's "
                    "DummyDevice plays empty (its streams carry no cropping record), record with rekon-oni-record");
    spdlog::info("openni2 '{}': end of recording after {} frames", uri_, frames_);
    return finish(Capture::Status::kEnded, "");
  }
  const double silent = std::chrono::duration<double>(std::chrono::steady_clock::now() - last_frame_).count();
  if (silent < kLostAfterS) return std::nullopt;
  const std::string quiet = " sent no frame for " + std::to_string(static_cast<int>(kLostAfterS)) + " s";
  return finish(Capture::Status::kLost,
                is_file_ ? "OpenNI2 recording '" + uri_ + "'" + quiet +
                               " before its end: it is truncated or corrupt; record it again (rekon-oni-record)"
                         : "OpenNI2 device '" + uri_ + "'" + quiet + "; check its USB cable and power, then start again");
}

std::optional<Capture> OpenNI2Source::readReady(int stream) {
  openni::VideoFrameRef frame;
  if (streams_[stream].readFrame(&frame) != openni::STATUS_OK || !frame.isValid())
    return finish(Capture::Status::kLost, "OpenNI2 device '" + uri_ + "': reading a " +
                                              (stream == 0 ? "depth" : "color") + " frame failed: " + oniError() +
                                              "; check its USB cable and power, then start again");
  streamed_[stream] = true;
  last_frame_ = std::chrono::steady_clock::now();
  recent_[stream].push_back(frame);
  if (recent_[stream].size() > kPairWindow) recent_[stream].pop_front();
  openni::VideoFrameRef depth, color;
  if (!takePair(depth, color)) return std::nullopt;
  return makeFrame(depth, color);
}

// The newest depth and color with the same frame index (the device numbers
// them alike: it syncs, or it is a recording of one that did); else, for a
// device that does not, the newest of each. Older frames are dropped.
bool OpenNI2Source::takePair(openni::VideoFrameRef& depth, openni::VideoFrameRef& color) {
  if (recent_[0].empty() || recent_[1].empty()) return false;
  if (pair_by_index_) {
    for (auto d = recent_[0].rbegin(); d != recent_[0].rend(); ++d) {
      for (const auto& c : recent_[1]) {
        if (c.getFrameIndex() != d->getFrameIndex()) continue;
        depth = *d;
        color = c;
        const int index = d->getFrameIndex();
        for (auto& recent : recent_)
          while (!recent.empty() && recent.front().getFrameIndex() <= index) recent.pop_front();
        mismatches_ = 0;
        return true;
      }
    }
    if (++mismatches_ <= kMaxIndexMismatches) return false;
    pair_by_index_ = false;
    spdlog::warn("openni2 '{}': depth and color frame indices never match (e.g. {} and {}): pairing the newest "
                 "of each",
                 uri_, recent_[0].back().getFrameIndex(), recent_[1].back().getFrameIndex());
  }
  depth = recent_[0].back();
  color = recent_[1].back();
  recent_[0].clear();
  recent_[1].clear();
  return true;
}

Capture OpenNI2Source::makeFrame(const openni::VideoFrameRef& depth, const openni::VideoFrameRef& color) {
  if (depth.getWidth() != color.getWidth() || depth.getHeight() != color.getHeight())
    return finish(Capture::Status::kLost, "OpenNI2 device '" + uri_ + "' sent depth " +
                                              std::to_string(depth.getWidth()) + "x" +
                                              std::to_string(depth.getHeight()) + " with color " +
                                              std::to_string(color.getWidth()) + "x" +
                                              std::to_string(color.getHeight()) +
                                              "; rekon needs one size (choose a mode both offer)");
  Capture capture;
  capture.status = Capture::Status::kFrame;
  // The device's exposure time (µs) on the host clock: as steady as the
  // device's, where the arrival time carries USB and scheduling jitter.
  // With camera.clock=recording, an .oni file's own device time instead.
  const double device_s = static_cast<double>(std::max(depth.getTimestamp(), color.getTimestamp())) * 1e-6;
  capture.host_time = hostWallSeconds();
  capture.frame.timestamp = recording_clock_ ? device_s : clock_.stamp(device_s, capture.host_time);
  const cv::Mat depth_mm(depth.getHeight(), depth.getWidth(), CV_16UC1, const_cast<void*>(depth.getData()),
                         static_cast<size_t>(depth.getStrideInBytes()));
  if (software_registration_) {
    cv::Mat metres;
    depth_mm.convertTo(metres, CV_32F, 0.001);
    capture.frame.depth = toMillimetres(software_registration_->apply(metres));
  } else {
    capture.frame.depth = depth_mm.clone();
  }
  const cv::Mat rgb(color.getHeight(), color.getWidth(), CV_8UC3, const_cast<void*>(color.getData()),
                    static_cast<size_t>(color.getStrideInBytes()));
  capture.frame.color.create(rgb.size(), CV_8UC3);
  const int rgb_to_bgr[] = {0, 2, 1, 1, 2, 0};
  cv::mixChannels(&rgb, 1, &capture.frame.color, 1, rgb_to_bgr, 3);
  if (frames_ > 0 && depth.getFrameIndex() > last_depth_index_ + 1)
    replaced_ += depth.getFrameIndex() - last_depth_index_ - 1;
  last_depth_index_ = depth.getFrameIndex();
  if (frames_ == 0)
    spdlog::info("openni2 '{}': first frame (device index {}, device time {:.3f} s)", uri_, depth.getFrameIndex(),
                 depth.getTimestamp() * 1e-6);
  ++frames_;
  return capture;
}

Capture OpenNI2Source::finish(Capture::Status status, const std::string& reason) {
  Capture capture;
  capture.status = status;
  capture.reason = reason;
  if (status == Capture::Status::kLost) spdlog::error("{}", reason);
  finished_ = capture;
  return capture;
}

// One line per mode, as `rekon cameras` prints them; the device must be open
// (OpenNI2 knows a device's sensors only then).
std::vector<std::string> listModes(openni::Device& device) {
  std::vector<std::string> modes;
  const bool registered = device.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR);
  for (const auto sensor : {openni::SENSOR_DEPTH, openni::SENSOR_COLOR}) {
    const openni::SensorInfo* info = device.getSensorInfo(sensor);
    if (info == nullptr) continue;
    const auto& offered = info->getSupportedVideoModes();
    for (int i = 0; i < offered.getSize(); ++i) {
      std::string line = std::string(sensor == openni::SENSOR_DEPTH ? "depth " : "color ") + modeText(offered[i]);
      if (sensor == openni::SENSOR_DEPTH && registered) line += " registered";
      if (std::find(modes.begin(), modes.end(), line) == modes.end()) modes.push_back(line);
    }
  }
  return modes;
}

std::string serialOf(openni::Device& device) {
  char serial[64] = {};
  int size = sizeof(serial);
  if (device.getProperty(openni::DEVICE_PROPERTY_SERIAL_NUMBER, serial, &size) != openni::STATUS_OK) return "";
  return std::string(serial, strnlen(serial, sizeof(serial)));
}

}  // namespace

std::unique_ptr<CameraSource> openOpenNI2(const std::string& uri, const SourceOptions& options) {
  return std::make_unique<OpenNI2Source>(uri, options);
}

// OpenNI2 reads a device's serial and modes only from an open device: each is
// opened briefly; one that cannot be (busy, no permission) is listed without.
std::vector<CameraInfo> listOpenNI2() {
  OpenNIScope scope;
  openni::Array<openni::DeviceInfo> devices;
  openni::OpenNI::enumerateDevices(&devices);
  std::vector<CameraInfo> list;
  for (int i = 0; i < devices.getSize(); ++i) {
    CameraInfo info;
    info.driver = "openni2";
    info.uri = devices[i].getUri();
    info.name = std::string(devices[i].getVendor()) + " " + devices[i].getName();
    openni::Device device;
    if (device.open(devices[i].getUri()) == openni::STATUS_OK) {
      info.serial = serialOf(device);
      info.modes = listModes(device);
      device.close();
    } else {
      info.modes.push_back("(cannot open to read its modes: " + oniError() + ")");
    }
    list.push_back(std::move(info));
  }
  return list;
}

}  // namespace rekon::camera
