// An OpenNI2 driver with one synthetic RGB-D device, URI "rekon-synth": what
// rekon-oni-record records when no camera is attached, so the tests exercise
// OpenNI2's own Recorder and its own file player (OniFile) end to end.
//
// Why not OpenNI2's DummyDevice: it streams, and the Recorder records it, but
// its streams answer no property except the video mode. The Recorder then
// writes no "xnCropping" record, and OniFile's PlayerStream, which reads the
// cropping of every frame it replays, silently drops every frame of such a
// recording (OpenNI2 2.2.0.33, Source/Drivers/OniFile/PlayerStream.cpp
// OnNewDataCallback). A PS1080 reports cropping, mirroring and its field of
// view; this device reports the same properties, so its recordings play.
//
// The images say which frame they are, so a reader can check pairing:
//   depth (mm, 320x240@30, DEPTH_1_MM): row 0 is 2000 (as DummyDevice's), every
//     other pixel 1000 + x + y + 10 * (k % 50) for frame index k (1, 2, ...)
//   color (RGB888, 320x240@30): R = k % 256, G = y, B = x % 256
// Device timestamps are k * 33333 us. URI "rekon-synth?vanish=N" disconnects
// the device (OpenNI2's device-disconnected event) after N frames, as an
// unplugged camera does.
#include <OniCProperties.h>
#include <OniCTypes.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <string>
#include <thread>

// ONI_EXPORT_DRIVER uses OpenNI2's internal allocation macros, which its
// public headers do not install.
#define XN_NEW(type, arg) new type(arg)
#define XN_DELETE(p) delete (p)
#include <Driver/OniDriverAPI.h>

namespace {

constexpr int kWidth = 320;
constexpr int kHeight = 240;
constexpr int kFps = 30;
constexpr uint64_t kFramePeriodUs = 33333;
// A PrimeSense color camera's field of view (what a PS1080 reports for 320x240):
// fx = 160 / tan(1.0225 / 2) = 285.2 px.
constexpr float kHorizontalFov = 1.0225f;
constexpr float kVerticalFov = 0.7941f;
constexpr const char* kUri = "rekon-synth";

uint16_t depthAt(int x, int y, int k) {
  return y == 0 ? 2000 : static_cast<uint16_t>(1000 + x + y + 10 * (k % 50));
}

void fillDepth(OniFrame& frame, int k) {
  auto* depth = static_cast<uint16_t*>(frame.data);
  for (int y = 0; y < kHeight; ++y)
    for (int x = 0; x < kWidth; ++x) depth[y * kWidth + x] = depthAt(x, y, k);
}

void fillColor(OniFrame& frame, int k) {
  auto* rgb = static_cast<uint8_t*>(frame.data);
  for (int y = 0; y < kHeight; ++y)
    for (int x = 0; x < kWidth; ++x) {
      uint8_t* pixel = rgb + 3 * (y * kWidth + x);
      pixel[0] = static_cast<uint8_t>(k % 256);
      pixel[1] = static_cast<uint8_t>(y);
      pixel[2] = static_cast<uint8_t>(x % 256);
    }
}

OniVideoMode videoModeOf(OniSensorType sensor) {
  OniVideoMode mode{};
  mode.pixelFormat = sensor == ONI_SENSOR_DEPTH ? ONI_PIXEL_FORMAT_DEPTH_1_MM : ONI_PIXEL_FORMAT_RGB888;
  mode.resolutionX = kWidth;
  mode.resolutionY = kHeight;
  mode.fps = kFps;
  return mode;
}

template <typename T>
OniStatus answer(const T& value, void* data, int* size) {
  if (*size != static_cast<int>(sizeof(T))) return ONI_STATUS_BAD_PARAMETER;
  std::memcpy(data, &value, sizeof(T));
  return ONI_STATUS_OK;
}

// Called once per generated frame; true when the device should vanish now.
using VanishCheck = bool (*)(void* device, int frame_index);

class SynthStream : public oni::driver::StreamBase {
 public:
  SynthStream(OniSensorType sensor, VanishCheck vanish, void* device)
      : sensor_(sensor), vanish_(vanish), device_(device) {}
  ~SynthStream() override { stop(); }

  OniStatus start() override {
    stop();
    running_ = true;
    thread_ = std::thread([this] { generate(); });
    return ONI_STATUS_OK;
  }
  // Joins the generator, so destroying the stream never races it (DummyDevice
  // lets its thread run on into the freed stream).
  void stop() override {
    running_ = false;
    if (thread_.joinable()) thread_.join();
  }

  OniStatus getProperty(int id, void* data, int* size) override {
    switch (id) {
      case ONI_STREAM_PROPERTY_VIDEO_MODE: return answer(videoModeOf(sensor_), data, size);
      case ONI_STREAM_PROPERTY_CROPPING: return answer(OniCropping{}, data, size);  // disabled
      case ONI_STREAM_PROPERTY_MIRRORING: return answer(OniBool(FALSE), data, size);
      case ONI_STREAM_PROPERTY_HORIZONTAL_FOV: return answer(kHorizontalFov, data, size);
      case ONI_STREAM_PROPERTY_VERTICAL_FOV: return answer(kVerticalFov, data, size);
      case ONI_STREAM_PROPERTY_MAX_VALUE: return answer(int(10000), data, size);
      case ONI_STREAM_PROPERTY_MIN_VALUE: return answer(int(0), data, size);
      default: return ONI_STATUS_NOT_SUPPORTED;
    }
  }
  OniBool isPropertySupported(int id) override {
    int size = 64;
    char scratch[64];
    return getProperty(id, scratch, &size) != ONI_STATUS_NOT_SUPPORTED;
  }
  // The one mode there is may be set (OpenNI2 sets it when asked); mirroring
  // may be turned off, never on.
  OniStatus setProperty(int id, const void* data, int size) override {
    if (id == ONI_STREAM_PROPERTY_VIDEO_MODE && size == sizeof(OniVideoMode)) {
      const auto* mode = static_cast<const OniVideoMode*>(data);
      const OniVideoMode ours = videoModeOf(sensor_);
      const bool same = mode->pixelFormat == ours.pixelFormat && mode->resolutionX == ours.resolutionX &&
                        mode->resolutionY == ours.resolutionY && mode->fps == ours.fps;
      return same ? ONI_STATUS_OK : ONI_STATUS_NOT_SUPPORTED;
    }
    if (id == ONI_STREAM_PROPERTY_MIRRORING && size == sizeof(OniBool))
      return *static_cast<const OniBool*>(data) ? ONI_STATUS_NOT_SUPPORTED : ONI_STATUS_OK;
    return ONI_STATUS_NOT_SUPPORTED;
  }

 private:
  void generate() {
    const auto start = std::chrono::steady_clock::now();
    for (int k = 1; running_; ++k) {
      std::this_thread::sleep_until(start + std::chrono::microseconds(kFramePeriodUs * k));
      if (vanish_(device_, k)) return;
      OniFrame* frame = getServices().acquireFrame();
      if (frame == nullptr) continue;
      sensor_ == ONI_SENSOR_DEPTH ? fillDepth(*frame, k) : fillColor(*frame, k);
      frame->sensorType = sensor_;
      frame->frameIndex = k;
      frame->timestamp = kFramePeriodUs * static_cast<uint64_t>(k);
      frame->videoMode = videoModeOf(sensor_);
      frame->width = kWidth;
      frame->height = kHeight;
      frame->croppingEnabled = FALSE;
      frame->cropOriginX = frame->cropOriginY = 0;
      frame->stride = kWidth * (sensor_ == ONI_SENSOR_DEPTH ? 2 : 3);
      raiseNewFrame(frame);
      getServices().releaseFrame(frame);
    }
  }

  OniSensorType sensor_;
  VanishCheck vanish_;
  void* device_;
  std::atomic<bool> running_{false};
  std::thread thread_;
};

class SynthDevice : public oni::driver::DeviceBase {
 public:
  SynthDevice(const OniDeviceInfo& info, int vanish_after, void (*disconnect)(void*, const OniDeviceInfo&),
              void* driver)
      : info_(info), vanish_after_(vanish_after), disconnect_(disconnect), driver_(driver) {
    for (int i = 0; i < 2; ++i) {
      modes_[i] = videoModeOf(i == 0 ? ONI_SENSOR_DEPTH : ONI_SENSOR_COLOR);
      sensors_[i].sensorType = i == 0 ? ONI_SENSOR_DEPTH : ONI_SENSOR_COLOR;
      sensors_[i].numSupportedVideoModes = 1;
      sensors_[i].pSupportedVideoModes = &modes_[i];
    }
  }

  OniStatus getSensorInfoList(OniSensorInfo** sensors, int* count) override {
    *sensors = sensors_;
    *count = 2;
    return ONI_STATUS_OK;
  }
  oni::driver::StreamBase* createStream(OniSensorType sensor) override {
    if (sensor != ONI_SENSOR_DEPTH && sensor != ONI_SENSOR_COLOR) return nullptr;
    return new SynthStream(sensor, &SynthDevice::shouldVanish, this);
  }
  void destroyStream(oni::driver::StreamBase* stream) override { delete stream; }
  OniStatus getProperty(int id, void* data, int* size) override {
    if (id != ONI_DEVICE_PROPERTY_SERIAL_NUMBER || *size < 16) return ONI_STATUS_NOT_SUPPORTED;
    std::strncpy(static_cast<char*>(data), "SYNTH0001", static_cast<size_t>(*size));
    return ONI_STATUS_OK;
  }
  OniBool isPropertySupported(int id) override { return id == ONI_DEVICE_PROPERTY_SERIAL_NUMBER; }

 private:
  // The first stream to reach frame N unplugs the device once; both stop.
  static bool shouldVanish(void* self, int frame_index) {
    auto* device = static_cast<SynthDevice*>(self);
    if (device->vanish_after_ <= 0 || frame_index <= device->vanish_after_) return false;
    std::call_once(device->vanished_, [device] { device->disconnect_(device->driver_, device->info_); });
    return true;
  }

  OniDeviceInfo info_;
  int vanish_after_;
  void (*disconnect_)(void*, const OniDeviceInfo&);
  void* driver_;
  std::once_flag vanished_;
  OniVideoMode modes_[2];
  OniSensorInfo sensors_[2];
};

class SynthDriver : public oni::driver::DriverBase {
 public:
  explicit SynthDriver(OniDriverServices* services) : DriverBase(services) {}

  // OpenNI2 asks every driver about a URI no driver has listed; ours are
  // "rekon-synth" and "rekon-synth?vanish=N".
  OniStatus tryDevice(const char* uri) override {
    const std::string text = uri;
    if (text.rfind(kUri, 0) != 0) return ONI_STATUS_ERROR;
    std::lock_guard<std::mutex> lock(mutex_);
    OniDeviceInfo info{};
    std::strncpy(info.uri, uri, ONI_MAX_STR - 1);
    std::strncpy(info.vendor, "rekon", ONI_MAX_STR - 1);
    std::strncpy(info.name, "synthetic RGB-D", ONI_MAX_STR - 1);
    deviceConnected(&info);
    return ONI_STATUS_OK;
  }
  oni::driver::DeviceBase* deviceOpen(const char* uri, const char* /*mode*/) override {
    const std::string text = uri;
    if (text.rfind(kUri, 0) != 0) return nullptr;
    const size_t vanish = text.find("vanish=");
    OniDeviceInfo info{};
    std::strncpy(info.uri, uri, ONI_MAX_STR - 1);
    std::strncpy(info.vendor, "rekon", ONI_MAX_STR - 1);
    std::strncpy(info.name, "synthetic RGB-D", ONI_MAX_STR - 1);
    const int after = vanish == std::string::npos ? 0 : std::atoi(text.c_str() + vanish + 7);
    return new SynthDevice(info, after, &SynthDriver::disconnect, this);
  }
  void deviceClose(oni::driver::DeviceBase* device) override { delete device; }
  void shutdown() override {}

 private:
  static void disconnect(void* self, const OniDeviceInfo& info) {
    static_cast<SynthDriver*>(self)->deviceDisconnected(&info);
  }
  std::mutex mutex_;
};

}  // namespace

ONI_EXPORT_DRIVER(SynthDriver)
