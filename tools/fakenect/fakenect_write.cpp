// rekon-fakenect-write --dataset TUM_DIR --out DIR: a TUM dataset as a
// recording for Debian's fakenect (libfreenect 0.5's record.c layout, see
// rekon/camera/fakenect_recording.hpp): depth quantised to the nearest Kinect
// 11-bit disparity value as a real Kinect would deliver it, color as PPM, an
// accelerometer dump after each frame as record.c writes one, and INDEX.txt.
// With --depth-offset X the depth is seen by a virtual IR camera X metres
// along the color camera's x axis (forward warp, nearest depth wins), and
// camera.yaml says so, so the driver's software registration has work to do.
#include <spdlog/spdlog.h>

#include <fmt/format.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <opencv2/core.hpp>
#include <optional>

#include "rekon/camera/fakenect_recording.hpp"
#include "rekon/camera/kinect_depth.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"

namespace {

using rekon::Error;
namespace cam = rekon::camera;
namespace fs = std::filesystem;

// sizeof(freenect_raw_tilt_state) on x86-64 and arm64: three int16, an int8
// and an enum. fakenect warns once and uses dummy values on any other size.
constexpr size_t kAccelerometerBytes = 12;
// An offset this large is a unit mistake (millimetres for metres).
constexpr double kMaxOffsetM = 1.0;

struct Options {
  std::string dataset, out;
  int frames = 0;
  double slowdown = 1.0;
  double depth_offset = 0.0;
};

std::optional<Options> parseOptions(int argc, char** argv) {
  rekon::ArgParser args(argv[0], "Write a TUM RGB-D dataset as a recording for Debian's fakenect replay library.");
  args.option("dataset", "TUM dataset folder (640x480)")
      .option("out", "output folder (created; must not hold a recording)")
      .option("frames", "number of frames (0 = all)", "0")
      .option("slowdown", "play K times slower than recorded (a 30 Hz sequence plays at 30/K Hz)", "1")
      .option("depth-offset", "metres along x from the color camera to a virtual IR camera (0 = depth aligned)", "0");
  if (!args.parse(argc, argv)) return std::nullopt;
  Options o;
  if (!args.has("dataset") || !args.has("out")) throw Error("missing --dataset DIR or --out DIR; see --help");
  o.dataset = args.get("dataset");
  o.out = args.get("out");
  o.frames = args.getInt("frames");
  o.slowdown = args.getDouble("slowdown");
  o.depth_offset = args.getDouble("depth-offset");
  if (o.frames < 0) throw Error("--frames " + std::to_string(o.frames) + " is negative; 0 means all frames");
  if (!(o.slowdown > 0.0)) throw Error("--slowdown must be positive (1 = the recorded rate)");
  if (std::abs(o.depth_offset) > kMaxOffsetM) {
    throw Error("--depth-offset " + fmt::format("{}", o.depth_offset) +
                " is over 1 m; give it in metres (a Kinect's is about 0.025)");
  }
  return o;
}

// The color camera of the dataset and, with an offset, the virtual IR camera
// beside it: same intrinsics, p_color = p_ir + (offset, 0, 0).
cam::KinectCalibration recordingCalibration(const rekon::Intrinsics& color, double offset) {
  cam::KinectCalibration c;
  c.color = color;
  c.color.depth_scale = 1000.0;  // what the driver delivers
  c.depth = c.color;
  c.aligned = offset == 0.0;
  c.depth_to_color_translation = Eigen::Vector3d(offset, 0.0, 0.0);
  return c;
}

// The depth the (virtual) IR camera sees, as 11-bit raw values.
cv::Mat rawDepth(const cv::Mat& depth, double depth_scale, const std::optional<cam::DepthWarp>& to_ir,
                 const cam::DisparityTable& table) {
  cv::Mat metres;
  depth.convertTo(metres, CV_32F, 1.0 / depth_scale);
  if (to_ir) metres = to_ir->apply(metres);
  cv::Mat raw(metres.size(), CV_16UC1);
  for (int v = 0; v < metres.rows; ++v) {
    const float* m = metres.ptr<float>(v);
    uint16_t* r = raw.ptr<uint16_t>(v);
    for (int u = 0; u < metres.cols; ++u) r[u] = m[u] > 0.0f ? table.nearestRaw(m[u]) : cam::DisparityTable::kNoValue;
  }
  return raw;
}

class RecordingWriter {
 public:
  explicit RecordingWriter(const std::string& dir) : dir_(dir) {
    rekon::createOutputFolder(dir);
    if (fs::exists(dir_ / "INDEX.txt")) {
      throw Error(dir + " already holds a recording (INDEX.txt); give an empty --out folder");
    }
    index_.open(dir_ / "INDEX.txt", std::ios::binary);
    if (!index_) throw Error(dir + "/INDEX.txt: cannot write; choose a writable --out");
  }

  // One entry named as record.c names it: TYPE-TIME(%f)-TICK(%u).EXT.
  void write(char type, double time, uint32_t tick, const char* ext, const std::string& header, const void* data,
             size_t bytes) {
    char name[96];
    std::snprintf(name, sizeof(name), "%c-%f-%u.%s", type, time, tick, ext);
    std::ofstream out(dir_ / name, std::ios::binary);
    out << header;
    out.write(static_cast<const char*>(data), static_cast<std::streamsize>(bytes));
    if (!out) throw Error((dir_ / name).string() + ": write failed (disk full?)");
    index_ << name << "\n";
    if (!index_) throw Error((dir_ / "INDEX.txt").string() + ": write failed (disk full?)");
  }

 private:
  fs::path dir_;
  std::ofstream index_;
};

// Raw depth as record.c stores it: the host's uint16 values, little-endian.
std::vector<uint8_t> littleEndian(const cv::Mat& raw) {
  std::vector<uint8_t> bytes(raw.total() * 2);
  size_t i = 0;
  for (int v = 0; v < raw.rows; ++v) {
    const uint16_t* r = raw.ptr<uint16_t>(v);
    for (int u = 0; u < raw.cols; ++u) {
      bytes[i++] = static_cast<uint8_t>(r[u] & 0xff);
      bytes[i++] = static_cast<uint8_t>(r[u] >> 8);
    }
  }
  return bytes;
}

int run(const Options& o) {
  rekon::DatasetOptions dataset_options;
  dataset_options.max_frames = o.frames;
  const rekon::TumDataset dataset(o.dataset, dataset_options);
  const rekon::Intrinsics& k = dataset.intrinsics();
  if (k.width != 640 || k.height != 480) {
    throw Error(o.dataset + ": frames are " + std::to_string(k.width) + "x" + std::to_string(k.height) +
                "; fakenect replays 640x480 only");
  }
  const cam::KinectCalibration calibration = recordingCalibration(k, o.depth_offset);
  std::optional<cam::DepthWarp> to_ir;
  if (!calibration.aligned)
    to_ir.emplace(calibration.color, calibration.depth, Eigen::Matrix3d::Identity(),
                  -calibration.depth_to_color_translation);
  const cam::DisparityTable table(calibration.disparity);
  RecordingWriter writer(o.out);
  // Times are the dataset's, stretched by --slowdown around the first (what
  // camera.clock=recording gives the frames). fakenect takes a recorded time
  // of 0 for "no previous entry" and would not wait before the second frame,
  // so a sequence starting at 0 starts at 1 s (score it with eval traj
  // --offset -1). A start at 1 µs instead paired depth and color images of
  // different frames in fakenect (the room's live ATE 0.2 -> 99 mm).
  const double first = dataset.timestamp(0);
  const double base = first > 0.0 ? first : 1.0;
  if (first <= 0.0)
    spdlog::info("the dataset starts at time 0: its frames are recorded from 1 s on (fakenect needs a start after 0)");
  const std::vector<uint8_t> accelerometer(kAccelerometerBytes, 0);  // level and still
  for (size_t i = 0; i < dataset.size(); ++i) {
    const rekon::RgbdFrame frame = dataset.load(i);
    const double time = base + (dataset.timestamp(i) - first) * o.slowdown;
    // Device ticks in microseconds of recorded time (their real unit is undocumented).
    const auto tick = static_cast<uint32_t>(std::llround((dataset.timestamp(i) - first) * 1e6) & 0xffffffffLL);
    const std::vector<uint8_t> depth = littleEndian(rawDepth(frame.depth, k.depth_scale, to_ir, table));
    cv::Mat rgb;
    const int bgr_to_rgb[] = {0, 2, 1, 1, 2, 0};
    rgb.create(frame.color.size(), CV_8UC3);
    cv::mixChannels(&frame.color, 1, &rgb, 1, bgr_to_rgb, 3);
    writer.write('d', time, tick, "pgm", cam::kFakenectDepthHeader, depth.data(), depth.size());
    writer.write('r', time, tick, "ppm", cam::kFakenectColorHeader, rgb.data, rgb.total() * 3);
    writer.write('a', time, tick, "dump", "", accelerometer.data(), accelerometer.size());
    if ((i + 1) % 100 == 0) spdlog::info("{} of {} frames written", i + 1, dataset.size());
  }
  cam::saveKinectCalibration(calibration, (fs::path(o.out) / "camera.yaml").string());
  spdlog::info(
      "fakenect recording {}: {} frames, {:.1f} s to play, depth {}; camera.yaml written beside it", o.out,
      dataset.size(), (dataset.timestamp(dataset.size() - 1) - first) * o.slowdown,
      calibration.aligned ? "aligned with color" : "seen from " + fmt::format("{}", o.depth_offset) + " m along x");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const std::optional<Options> options = parseOptions(argc, argv);
    return options ? run(*options) : 0;
  } catch (...) {
    spdlog::error("{}", rekon::currentExceptionLine());
    return 1;
  }
}
