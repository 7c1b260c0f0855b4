// The libfreenect driver: a Kinect v1 through libfreenect's C async API
// (callbacks called from freenect_process_events on our own event thread),
// and Debian's fakenect replay library (the same API, selected with
// LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect and FAKENECT_PATH=DIR).
// Depth and color arrive as separate callbacks and are paired here.
#include <dlfcn.h>
#include <libfreenect.h>
#include <libusb.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <opencv2/core.hpp>
#include <optional>
#include <thread>

#include "rekon/camera/fakenect_recording.hpp"
#include "rekon/camera/kinect_depth.hpp"
#include "rekon/camera/device_clock.hpp"
#include "rekon/camera/source.hpp"
#include "rekon/common/error.hpp"

namespace rekon::camera {

namespace {

constexpr int kWidth = 640;
constexpr int kHeight = 480;
constexpr int kFps = 30;
// A real Kinect that sent nothing for this long after streaming began has
// gone (libusb does not always report an unplugged device as an error).
constexpr double kStallS = 3.0;
// ... and one that has not started streaming this long after opening.
constexpr double kFirstFrameWaitS = 10.0;
// How long one freenect_process_events_timeout may block, so that closing the
// source never waits longer (fakenect ignores it and sleeps the recorded gap).
constexpr long kEventWaitUs = 100000;

const char* const kNoDeviceHint = "check the USB cable/power; rekon cameras lists what is connected";

using SteadyClock = std::chrono::steady_clock;

// fakenect keeps its place in a recording in process-wide state: opened again
// in the same process (rekon-camera reopening a lost device), it goes on from
// the entry where it stopped, as a real device goes on streaming. The entries
// played so far, across every source of this process.
std::atomic<size_t> g_fakenect_entries_played{0};

void logFromFreenect(freenect_context*, freenect_loglevel level, const char* message) {
  std::string text(message ? message : "");
  while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.pop_back();
  if (level <= FREENECT_LOG_ERROR) {
    spdlog::error("libfreenect: {}", text);
  } else if (level == FREENECT_LOG_WARNING) {
    spdlog::warn("libfreenect: {}", text);
  } else {
    spdlog::debug("libfreenect: {}", text);
  }
}

// Debian's fakenect (0.5) exports no freenect_list_device_attributes; the real
// library does. Looked up at run time so one binary loads against both.
using ListAttributes = int (*)(freenect_context*, freenect_device_attributes**);
using FreeAttributes = void (*)(freenect_device_attributes*);
ListAttributes listAttributesFunction() {
  return reinterpret_cast<ListAttributes>(dlsym(RTLD_DEFAULT, "freenect_list_device_attributes"));
}
bool fakenectLoaded() {
  return listAttributesFunction() == nullptr;
}

std::string depthFormatName(freenect_depth_format f) {
  switch (f) {
    case FREENECT_DEPTH_11BIT: return "11-bit";
    case FREENECT_DEPTH_10BIT: return "10-bit";
    case FREENECT_DEPTH_11BIT_PACKED: return "11-bit packed";
    case FREENECT_DEPTH_10BIT_PACKED: return "10-bit packed";
    case FREENECT_DEPTH_REGISTERED: return "registered";
    case FREENECT_DEPTH_MM: return "mm";
    default: return "format " + std::to_string(static_cast<int>(f));
  }
}

std::string videoFormatName(freenect_video_format f) {
  switch (f) {
    case FREENECT_VIDEO_RGB: return "rgb";
    case FREENECT_VIDEO_BAYER: return "bayer";
    case FREENECT_VIDEO_IR_8BIT: return "ir 8-bit";
    case FREENECT_VIDEO_IR_10BIT: return "ir 10-bit";
    case FREENECT_VIDEO_IR_10BIT_PACKED: return "ir 10-bit packed";
    case FREENECT_VIDEO_YUV_RGB: return "yuv rgb";
    case FREENECT_VIDEO_YUV_RAW: return "yuv raw";
    default: return "format " + std::to_string(static_cast<int>(f));
  }
}

std::string modeName(const char* stream, const freenect_frame_mode& m, const std::string& format) {
  return std::string(stream) + " " + std::to_string(m.width) + "x" + std::to_string(m.height) + "@" +
         std::to_string(m.framerate) + " " + format;
}

// Every mode the library offers, as `rekon cameras` prints them. Only the
// enumeration functions are used: Debian's fakenect asserts in
// freenect_find_*_mode on any format but 11-bit depth and RGB.
std::vector<std::string> offeredModes() {
  std::vector<std::string> modes;
  for (int i = 0; i < freenect_get_depth_mode_count(); ++i) {
    const freenect_frame_mode m = freenect_get_depth_mode(i);
    if (m.is_valid) modes.push_back(modeName("depth", m, depthFormatName(m.depth_format)));
  }
  for (int i = 0; i < freenect_get_video_mode_count(); ++i) {
    const freenect_frame_mode m = freenect_get_video_mode(i);
    if (m.is_valid) modes.push_back(modeName("color", m, videoFormatName(m.video_format)));
  }
  return modes;
}

std::optional<freenect_frame_mode> offeredDepthMode(freenect_depth_format format) {
  for (int i = 0; i < freenect_get_depth_mode_count(); ++i) {
    const freenect_frame_mode m = freenect_get_depth_mode(i);
    if (m.is_valid && m.depth_format == format && m.width == kWidth && m.height == kHeight) return m;
  }
  return std::nullopt;
}

std::optional<freenect_frame_mode> offeredVideoMode(freenect_video_format format) {
  for (int i = 0; i < freenect_get_video_mode_count(); ++i) {
    const freenect_frame_mode m = freenect_get_video_mode(i);
    if (m.is_valid && m.video_format == format && m.width == kWidth && m.height == kHeight) return m;
  }
  return std::nullopt;
}

// A libfreenect context and one open device, closed in the right order.
struct FreenectHandles {
  freenect_context* context = nullptr;
  freenect_device* device = nullptr;
  FreenectHandles() = default;
  FreenectHandles(const FreenectHandles&) = delete;
  FreenectHandles& operator=(const FreenectHandles&) = delete;
  ~FreenectHandles() {
    if (device) freenect_close_device(device);
    if (context) freenect_shutdown(context);
  }
};

void initContext(FreenectHandles& h) {
  if (freenect_init(&h.context, nullptr) < 0) {
    h.context = nullptr;
    throw Error("freenect: libfreenect could not initialise libusb; " + std::string(kNoDeviceHint));
  }
  freenect_set_log_callback(h.context, logFromFreenect);
  freenect_set_log_level(h.context, FREENECT_LOG_NOTICE);
  // Only the cameras: the motor and audio are not ours to claim.
  freenect_select_subdevices(h.context, FREENECT_DEVICE_CAMERA);
}

// Serials by device index, when the library reports them.
std::vector<std::string> deviceSerials(freenect_context* context) {
  std::vector<std::string> serials;
  const ListAttributes list = listAttributesFunction();
  const auto release = reinterpret_cast<FreeAttributes>(dlsym(RTLD_DEFAULT, "freenect_free_device_attributes"));
  if (!list || !release) return serials;
  freenect_device_attributes* attributes = nullptr;
  if (list(context, &attributes) < 0) return serials;
  for (const freenect_device_attributes* a = attributes; a; a = a->next)
    serials.emplace_back(a->camera_serial ? a->camera_serial : "");
  release(attributes);
  return serials;
}

int parseIndex(const std::string& index) {
  if (index.empty()) return 0;
  char* end = nullptr;
  const long v = std::strtol(index.c_str(), &end, 10);
  if (end != index.c_str() + index.size() || v < 0 || v > 1000) {
    throw Error("camera 'freenect:" + index + "': the device is a number (freenect:0 is the first Kinect); " +
                "rekon cameras lists what is connected");
  }
  return static_cast<int>(v);
}

// The newest depth and color images, as the callbacks delivered them.
struct RawPair {
  std::vector<uint8_t> depth, color;
  double host_time = 0.0;  // host wall clock when the later of the two arrived
  double timestamp = 0.0;  // host_time, or the recording's time of the depth image (SourceOptions::recording_clock)
};

class FreenectSource final : public CameraSource {
 public:
  FreenectSource(int index, const SourceOptions& options);
  ~FreenectSource() override;
  Capture next(double timeout_s) override;
  Intrinsics intrinsics() const override { return intrinsics_; }
  std::string describe() const override { return description_; }
  int64_t framesReplaced() const override {
    std::lock_guard<std::mutex> lock(mutex_);
    return replaced_;
  }

 private:
  void openDevice();
  void chooseDepth(const SourceOptions& options);
  void startStreams();
  void eventLoop();
  std::string stoppedReason(int rc) const;
  void finish(Capture::Status status, const std::string& reason);
  std::optional<Capture> checkStall();
  RgbdFrame toFrame(const RawPair& pair) const;
  static void onDepth(freenect_device* device, void* data, uint32_t timestamp);
  static void onVideo(freenect_device* device, void* data, uint32_t timestamp);
  void arrived(bool depth, const void* data, uint32_t device_timestamp);

  const int index_;
  const std::string name_;  // "freenect:0"
  std::optional<RecordingCheck> recording_;
  bool recording_clock_ = false;
  FreenectHandles handles_;
  freenect_frame_mode depth_mode_{}, video_mode_{};
  bool registered_ = false;  // FREENECT_DEPTH_REGISTERED: millimetres aligned by libfreenect
  std::optional<KinectRegistration> registration_;
  Intrinsics intrinsics_;
  std::string description_;

  // Event thread only: what arrived since the last pair.
  RawPair staging_;
  bool new_depth_ = false, new_color_ = false;
  uint32_t depth_tick_ = 0;  // of the staged depth image
  size_t events_ = 0;

  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::optional<RawPair> ready_;                      // newest wins: an unread pair is replaced
  Capture::Status stream_ = Capture::Status::kFrame;  // kFrame while running
  std::string end_reason_;
  SteadyClock::time_point last_pair_ = SteadyClock::now();
  bool any_pair_ = false;
  int64_t pairs_ = 0, replaced_ = 0;

  std::atomic<bool> stop_{false};
  std::thread thread_;
};

FreenectSource::FreenectSource(int index, const SourceOptions& options)
    : index_(index), name_("freenect:" + std::to_string(index)) {
  if (options.width != kWidth || options.height != kHeight || options.fps != kFps) {
    throw Error(name_ + ": the Kinect v1 streams registered depth and color at 640x480@30 only (asked for " +
                std::to_string(options.width) + "x" + std::to_string(options.height) + "@" +
                std::to_string(options.fps) + ")");
  }
  recording_ = checkReplayEnvironment(fakenectLoaded());
  if (recording_) events_ = g_fakenect_entries_played.load();
  recording_clock_ = options.recording_clock;
  if (recording_clock_ && !recording_)
    throw Error(name_ + ": camera.clock is 'recording' but this is a live Kinect, which has only this computer's clock; "
                "set camera.clock=host (or play a fakenect recording)");
  openDevice();
  chooseDepth(options);
  startStreams();
  thread_ = std::thread([this] { eventLoop(); });
}

void FreenectSource::openDevice() {
  initContext(handles_);
  const int count = freenect_num_devices(handles_.context);
  if (index_ >= count) {
    throw Error(name_ + ": no Kinect at index " + std::to_string(index_) + " (" + std::to_string(std::max(count, 0)) +
                " connected); " + kNoDeviceHint);
  }
  if (freenect_open_device(handles_.context, &handles_.device, index_) < 0) {
    handles_.device = nullptr;
    throw Error(name_ + ": cannot open the Kinect: another program has it, or this user may not use it " +
                "(install Debian's libfreenect udev rules and re-plug); " + kNoDeviceHint);
  }
  const std::optional<freenect_frame_mode> video = offeredVideoMode(FREENECT_VIDEO_RGB);
  if (!video) throw Error(name_ + ": the device offers no 640x480 RGB color mode");
  video_mode_ = *video;
}

void FreenectSource::chooseDepth(const SourceOptions& options) {
  const std::optional<freenect_frame_mode> registered = offeredDepthMode(FREENECT_DEPTH_REGISTERED);
  const std::optional<freenect_frame_mode> raw = offeredDepthMode(FREENECT_DEPTH_11BIT);
  if (!registered && !raw) throw Error(name_ + ": the device offers neither registered nor 11-bit depth at 640x480");
  registered_ = registered.has_value();
  depth_mode_ = registered_ ? *registered : *raw;
  const std::string device = recording_ ? "fakenect recording " + recording_->dir : name_ + " (Kinect v1)";
  KinectCalibration calibration = KinectCalibration::nominal();
  std::string source = "nominal Kinect v1 calibration";
  if (options.calibration_file) {
    calibration = loadKinectCalibration(*options.calibration_file);
    source = "calibration " + *options.calibration_file;
    if (registered_ && !calibration.aligned) {
      spdlog::info("{}: libfreenect registers the depth; the depth-camera keys of {} are not used", name_,
                   *options.calibration_file);
    }
  } else {
    spdlog::warn(
        "{}: no --calibration: using the nominal Kinect v1 ({}); calibrate the camera and pass --calibration "
        "camera.yaml for accurate maps",
        name_,
        registered_ ? "color fx=fy=525 cx=319.5 cy=239.5"
                    : "color fx=fy=525, IR fx=fy=580, color camera 2.5 cm right of the IR camera");
  }
  if (calibration.color.width != kWidth || calibration.color.height != kHeight) {
    throw Error(source + ": the camera is " + std::to_string(calibration.color.width) + "x" +
                std::to_string(calibration.color.height) + " but the Kinect streams 640x480");
  }
  intrinsics_ = calibration.color;
  intrinsics_.depth_scale = 1000.0;  // millimetres, whatever the file says
  if (!registered_) registration_.emplace(calibration);
  const std::string depth =
      registered_ ? "depth registered by libfreenect (mm)"
                  : std::string("11-bit depth ") + (calibration.aligned ? "already aligned" : "registered in software");
  description_ = device + ": " + depth + ", color RGB 640x480@30, " + source;
}

void FreenectSource::startStreams() {
  freenect_device* d = handles_.device;
  freenect_set_user(d, this);
  if (freenect_set_depth_mode(d, depth_mode_) < 0 || freenect_set_video_mode(d, video_mode_) < 0) {
    throw Error(name_ + ": the Kinect refused the depth or color mode; " + kNoDeviceHint);
  }
  freenect_set_depth_callback(d, &FreenectSource::onDepth);
  freenect_set_video_callback(d, &FreenectSource::onVideo);
  if (freenect_start_depth(d) < 0 || freenect_start_video(d) < 0) {
    throw Error(name_ + ": the Kinect would not start streaming; " + kNoDeviceHint);
  }
}

FreenectSource::~FreenectSource() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (handles_.device) {
    freenect_stop_depth(handles_.device);
    freenect_stop_video(handles_.device);
  }
  if (replaced_ > 0)
    spdlog::info("{}: {} of {} frames were replaced by newer ones before they were taken", name_, replaced_, pairs_);
}

void FreenectSource::eventLoop() {
  try {
    while (!stop_) {
      if (recording_ && events_ == recording_->playable) {
        // Every good entry has played: the end, or the first bad entry.
        if (recording_->bad.empty()) {
          finish(Capture::Status::kEnded, "");
        } else {
          finish(Capture::Status::kLost, recording_->bad);
        }
        return;
      }
      timeval wait{0, kEventWaitUs};
      const int rc = freenect_process_events_timeout(handles_.context, &wait);
      ++events_;
      if (recording_) g_fakenect_entries_played.store(events_);
      if (rc == LIBUSB_ERROR_INTERRUPTED) continue;  // a signal woke libusb; not an error
      if (rc < 0) {
        finish(Capture::Status::kLost, stoppedReason(rc));
        return;
      }
    }
  } catch (...) {
    finish(Capture::Status::kLost, name_ + ": " + currentExceptionLine());
  }
}

// Why freenect_process_events failed: a real device is gone; fakenect could
// not read an entry that was whole when the recording was checked.
std::string FreenectSource::stoppedReason(int rc) const {
  if (recording_) {
    return "fakenect recording " + recording_->dir + ": fakenect stopped after " + std::to_string(events_ - 1) +
           " of " + std::to_string(recording_->playable) + " entries (was the recording changed while it played?)";
  }
  return name_ + ": the Kinect stopped responding (libfreenect error " + std::to_string(rc) + "); " + kNoDeviceHint;
}

void FreenectSource::finish(Capture::Status status, const std::string& reason) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stream_ = status;
    end_reason_ = reason;
  }
  wake_.notify_all();
}

void FreenectSource::onDepth(freenect_device* device, void* data, uint32_t timestamp) {
  static_cast<FreenectSource*>(freenect_get_user(device))->arrived(true, data, timestamp);
}

void FreenectSource::onVideo(freenect_device* device, void* data, uint32_t timestamp) {
  static_cast<FreenectSource*>(freenect_get_user(device))->arrived(false, data, timestamp);
}

// Pairs in arrival order: a frame once both a new depth and a new color have
// come since the last one. The device timestamps have no documented unit, so
// they are only logged; frames carry the host's clock. Kept short: fakenect
// adds the time spent in a callback to every recorded gap, and a real device's
// USB transfers wait for it; the one copy is out of the library's buffer.
void FreenectSource::arrived(bool depth, const void* data, uint32_t device_timestamp) {
  spdlog::trace("{}: {} device timestamp {}", name_, depth ? "depth" : "color", device_timestamp);
  std::vector<uint8_t>& buffer = depth ? staging_.depth : staging_.color;
  const auto bytes = static_cast<size_t>(depth ? depth_mode_.bytes : video_mode_.bytes);
  const auto* begin = static_cast<const uint8_t*>(data);
  buffer.assign(begin, begin + bytes);
  (depth ? new_depth_ : new_color_) = true;
  if (depth) depth_tick_ = device_timestamp;
  if (!new_depth_ || !new_color_) return;
  new_depth_ = new_color_ = false;
  staging_.host_time = hostWallSeconds();
  staging_.timestamp = staging_.host_time;
  if (recording_clock_) {
    const auto it = recording_->depth_times.find(depth_tick_);
    if (it != recording_->depth_times.end()) staging_.timestamp = it->second;
    else spdlog::warn("{}: depth tick {} is not in {}/INDEX.txt; this frame has the host clock", name_, depth_tick_, recording_->dir);
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (ready_) ++replaced_;
    ++pairs_;
    if (!ready_) ready_.emplace();
    std::swap(*ready_, staging_);  // staging_ keeps the replaced buffers, or none
    last_pair_ = SteadyClock::now();
    any_pair_ = true;
  }
  wake_.notify_all();
}

Capture FreenectSource::next(double timeout_s) {
  std::unique_lock<std::mutex> lock(mutex_);
  wake_.wait_for(lock, std::chrono::duration<double>(std::max(timeout_s, 0.0)),
                 [&] { return ready_.has_value() || stream_ != Capture::Status::kFrame; });
  Capture capture;
  if (ready_) {
    // A frame already paired is delivered before the end is reported.
    const RawPair pair = std::move(*ready_);
    ready_.reset();
    lock.unlock();
    capture.status = Capture::Status::kFrame;
    capture.frame = toFrame(pair);
    capture.host_time = pair.host_time;
    return capture;
  }
  if (stream_ != Capture::Status::kFrame) {
    capture.status = stream_;
    capture.reason = end_reason_;
    return capture;
  }
  lock.unlock();
  if (std::optional<Capture> stalled = checkStall()) return *stalled;
  capture.status = Capture::Status::kTimeout;
  return capture;
}

// A real device that stopped sending frames is lost even when libusb reports
// nothing; a recording may pause as long as it was recorded to.
std::optional<Capture> FreenectSource::checkStall() {
  if (recording_) return std::nullopt;
  std::lock_guard<std::mutex> lock(mutex_);
  const double silent = std::chrono::duration<double>(SteadyClock::now() - last_pair_).count();
  const double limit = any_pair_ ? kStallS : kFirstFrameWaitS;
  if (silent < limit) return std::nullopt;
  Capture capture;
  capture.status = Capture::Status::kLost;
  capture.reason = name_ + ": no frames for " + std::to_string(static_cast<int>(silent)) + " s; " + kNoDeviceHint;
  return capture;
}

RgbdFrame FreenectSource::toFrame(const RawPair& pair) const {
  RgbdFrame frame;
  frame.timestamp = pair.timestamp;
  // The buffers are owned by `pair`: wrap, then copy or convert out of them.
  const cv::Mat depth(kHeight, kWidth, CV_16UC1, const_cast<uint8_t*>(pair.depth.data()));
  frame.depth = registered_ ? depth.clone() : registration_->apply(depth);
  const cv::Mat rgb(kHeight, kWidth, CV_8UC3, const_cast<uint8_t*>(pair.color.data()));
  frame.color.create(kHeight, kWidth, CV_8UC3);
  const int rgb_to_bgr[] = {0, 2, 1, 1, 2, 0};
  cv::mixChannels(&rgb, 1, &frame.color, 1, rgb_to_bgr, 3);
  return frame;
}

}  // namespace

std::unique_ptr<CameraSource> openFreenect(const std::string& index, const SourceOptions& options) {
  auto source = std::make_unique<FreenectSource>(parseIndex(index), options);
  spdlog::info("{}", source->describe());
  return source;
}

std::vector<CameraInfo> listFreenect() {
  FreenectHandles handles;
  initContext(handles);
  const int count = freenect_num_devices(handles.context);
  if (count < 0) throw Error("freenect: libusb could not list the USB devices; " + std::string(kNoDeviceHint));
  const std::vector<std::string> serials = deviceSerials(handles.context);
  const char* replay = std::getenv("FAKENECT_PATH");
  const bool fakenect = fakenectLoaded();
  std::vector<CameraInfo> infos;
  for (int i = 0; i < count; ++i) {
    CameraInfo info;
    info.driver = "freenect";
    info.uri = std::to_string(i);
    info.name = fakenect ? "fakenect recording " + std::string(replay ? replay : "(FAKENECT_PATH unset)")
                         : "Microsoft Kinect v1";
    if (static_cast<size_t>(i) < serials.size()) info.serial = serials[static_cast<size_t>(i)];
    info.modes = offeredModes();
    infos.push_back(std::move(info));
  }
  return infos;
}

}  // namespace rekon::camera
