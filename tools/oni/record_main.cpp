// rekon-oni-record --device URI --out FILE.oni --frames N: records an OpenNI2
// device's depth and color streams with OpenNI2's own openni::Recorder, the
// way a user records a Kinect or Xtion for `rekon run --camera openni2:FILE.oni`.
// With no camera attached, --device rekon-synth records the synthetic device
// of synth_driver.cpp (what the tests do); OpenNI2's "Dummy" records too, but
// OpenNI2 replays such a file without a single frame (synth_driver.cpp).
#include <OpenNI.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <filesystem>
#include <set>
#include <string>
#include <thread>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/common/threads.hpp"

namespace {

// Without frames for this long the device is not streaming: a line, not a hang.
constexpr int kFrameTimeoutMs = 5000;
// OpenNI2's Recorder starts recording on its own thread some time after
// start() returns, and drops the frames raised before (measured: 16 of 60 on
// a loaded machine). Only the file shows when it has begun: its metadata
// records (stream properties, a few KB, up to ~30 KB with PS1080's depth
// tables) come first and stop; then frame records, each at least one image.
constexpr auto kPollPeriod = std::chrono::milliseconds(20);
constexpr auto kSettledAfter = std::chrono::milliseconds(200);
constexpr uintmax_t kMoreThanMetadata = 2048;  // bytes beyond the settled metadata
// A driver's stream threads outlive stop(): DummyDevice's stop() only clears
// a flag, and its thread raises one more frame into the stream before it
// looks. Destroying the stream before that thread ends crashed (a sleep of
// 150 ms, then 400 ms, still crashed in CI rehearsals on a loaded machine), so
// stop() waits for the threads start() started to end. A driver whose threads
// stay (a real device's USB thread, say) is waited for this long at most.
constexpr auto kDriverThreadsEnd = std::chrono::milliseconds(5000);

std::string oniError() {
  std::string text = openni::OpenNI::getExtendedError();
  for (char& c : text)
    if (c == '\n' || c == '\r' || c == '\t') c = ' ';
  while (!text.empty() && text.back() == ' ') text.pop_back();
  return text.empty() ? "no detail from OpenNI2" : text;
}

void check(openni::Status status, const std::string& what) {
  if (status != openni::STATUS_OK) throw rekon::Error(what + ": " + oniError());
}

struct Streams {
  openni::VideoStream depth, color;
  bool running = false;
  std::set<int> driver_threads;  // what start() started
  void start(const std::string& uri) {
    running = true;
    driver_threads = rekon::threadsStartedBy([&] {
      check(depth.start(), "cannot start the depth stream of '" + uri + "'");
      check(color.start(), "cannot start the color stream of '" + uri + "'");
    });
  }
  void stop() {
    if (!running) return;
    depth.stop();
    color.stop();
    if (!rekon::waitForThreadsToEnd(driver_threads, kDriverThreadsEnd))
      spdlog::warn("the driver's stream threads still run {} ms after stop", kDriverThreadsEnd.count());
    running = false;
  }
  ~Streams() {
    stop();
    depth.destroy();
    color.destroy();
  }
};

uintmax_t fileSize(const std::string& path) {
  std::error_code error;
  const uintmax_t size = std::filesystem::file_size(path, error);
  return error ? 0 : size;
}

// The size of the file once the Recorder has written what it writes before
// any frame (it changes no more for kSettledAfter).
uintmax_t settledSize(const std::string& path) {
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::milliseconds(kFrameTimeoutMs);
  uintmax_t size = fileSize(path);
  auto since = std::chrono::steady_clock::now();
  while (std::chrono::steady_clock::now() < give_up) {
    std::this_thread::sleep_for(kPollPeriod);
    const uintmax_t now = fileSize(path);
    if (now != size) size = now, since = std::chrono::steady_clock::now();
    if (size > 0 && std::chrono::steady_clock::now() - since >= kSettledAfter) return size;
  }
  throw rekon::Error("OpenNI2's recorder wrote nothing to '" + path + "' in " +
                     std::to_string(kFrameTimeoutMs / 1000) + " s; check the disk and the folder's permissions");
}

// Reads until both streams have delivered `frames` frames since the first
// each delivered (device frame indices, so a slow reader does not record
// fewer than asked).
void readFrames(Streams& streams, int frames, const std::string& uri) {
  openni::VideoStream* both[2] = {&streams.depth, &streams.color};
  int first[2] = {-1, -1}, last[2] = {-1, -1};
  auto done = [&](int i) { return first[i] >= 0 && last[i] - first[i] + 1 >= frames; };
  while (!done(0) || !done(1)) {
    int ready = -1;
    if (openni::OpenNI::waitForAnyStream(both, 2, &ready, kFrameTimeoutMs) != openni::STATUS_OK)
      throw rekon::Error("device '" + uri + "' sent no frame for " + std::to_string(kFrameTimeoutMs / 1000) +
                         " s: " + oniError() + "; check that it streams (rekon cameras)");
    openni::VideoFrameRef frame;
    check(both[ready]->readFrame(&frame), "reading a frame of '" + uri + "'");
    if (first[ready] < 0) first[ready] = frame.getFrameIndex();
    last[ready] = frame.getFrameIndex();
  }
}

// Frames are counted only once the Recorder writes them (kMoreThanMetadata).
void recordFrames(Streams& streams, int frames, const std::string& uri, const std::string& out,
                  uintmax_t metadata) {
  openni::VideoStream* both[2] = {&streams.depth, &streams.color};
  while (fileSize(out) <= metadata + kMoreThanMetadata) {
    int ready = -1;
    if (openni::OpenNI::waitForAnyStream(both, 2, &ready, kFrameTimeoutMs) != openni::STATUS_OK)
      throw rekon::Error("device '" + uri + "' sent no frame for " + std::to_string(kFrameTimeoutMs / 1000) +
                         " s: " + oniError() + "; check that it streams (rekon cameras)");
    openni::VideoFrameRef frame;
    check(both[ready]->readFrame(&frame), "reading a frame of '" + uri + "'");
  }
  readFrames(streams, frames, uri);
}

// What OpenNI2's own file device finds in the recording: proves it plays.
std::pair<int, int> framesInFile(const std::string& path) {
  openni::Device file;
  const std::set<int> player_threads =
      rekon::threadsStartedBy([&] { check(file.open(path.c_str()), "OpenNI2 cannot open the recording '" + path + "' it wrote"); });
  // Closed before its thread first ran, the file device would lose the close (rekon/common/threads.hpp).
  rekon::waitForThreadsToBlock(player_threads, kDriverThreadsEnd);
  openni::VideoStream depth, color;
  check(depth.create(file, openni::SENSOR_DEPTH), "no depth stream in '" + path + "'");
  check(color.create(file, openni::SENSOR_COLOR), "no color stream in '" + path + "'");
  openni::PlaybackControl* playback = file.getPlaybackControl();
  return {playback->getNumberOfFrames(depth), playback->getNumberOfFrames(color)};
}

void record(const std::string& uri, const std::string& out, int frames) {
  openni::Device device;
  check(device.open(uri.empty() ? openni::ANY_DEVICE : uri.c_str()),
        "cannot open OpenNI2 device '" + uri + "' (rekon cameras lists devices)");
  Streams streams;
  check(streams.depth.create(device, openni::SENSOR_DEPTH), "no depth stream on '" + uri + "'");
  check(streams.color.create(device, openni::SENSOR_COLOR), "no color stream on '" + uri + "'");
  streams.depth.setMirroringEnabled(false);  // not every device can; the default then stays
  streams.color.setMirroringEnabled(false);

  const auto start = std::chrono::steady_clock::now();
  {
    openni::Recorder recorder;
    check(recorder.create(out.c_str()), "cannot create '" + out + "'");
    // Lossless color: the recording is a test oracle as much as a dataset.
    check(recorder.attach(streams.depth, false), "cannot record the depth stream");
    check(recorder.attach(streams.color, false), "cannot record the color stream");
    const uintmax_t metadata = settledSize(out);
    check(recorder.start(), "cannot start recording to '" + out + "'");
    streams.start(uri);
    // The streams stop before the Recorder goes, on every path: destroying it
    // while a stream still raises frames deadlocks OpenNI2 2.2 (its destructor
    // holds the Recorder's stream list and waits for the stream's recorder
    // list; the stream's frame thread holds that and waits for the first):
    // measured 1 hang in ~40 recordings of Dummy before this.
    struct StopStreamsFirst {
      Streams& streams;
      ~StopStreamsFirst() { streams.stop(); }
    } stop_streams_first{streams};
    recordFrames(streams, frames, uri, out, metadata);
    recorder.stop();
  }  // the Recorder writes its last frames and its seek tables when destroyed
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const auto [depth_frames, color_frames] = framesInFile(out);
  const openni::VideoMode depth = streams.depth.getVideoMode(), color = streams.color.getVideoMode();
  spdlog::info("recorded {} depth and {} color frames ({} asked) of '{}' ({} {}) to {} in {:.2f} s: depth {}x{}@{}, "
               "color {}x{}@{}",
               depth_frames, color_frames, frames, uri, device.getDeviceInfo().getVendor(),
               device.getDeviceInfo().getName(), out, seconds, depth.getResolutionX(), depth.getResolutionY(),
               depth.getFps(), color.getResolutionX(), color.getResolutionY(), color.getFps());
  if (depth_frames < frames || color_frames < frames)
    throw rekon::Error("'" + out + "' holds fewer frames than asked; record again");
}

}  // namespace

int main(int argc, char** argv) {
  try {
    rekon::setupLogging("oni-record", "info");
    rekon::ArgParser args("rekon-oni-record", "Record an OpenNI2 device's depth and color into an .oni file");
    args.option("device", "OpenNI2 device URI (rekon cameras lists them); empty = the first device", "")
        .option("out", "the .oni file to write")
        .option("frames", "frames to record", "300");
    if (!args.parse(argc, argv)) return 0;
    if (!args.has("out")) throw rekon::Error("rekon-oni-record: --out FILE.oni is required");
    const int frames = args.getInt("frames");
    if (frames < 1) throw rekon::Error("rekon-oni-record: --frames must be at least 1");
    if (openni::OpenNI::initialize() != openni::STATUS_OK)
      throw rekon::Error("OpenNI2 failed to initialise: " + oniError());
    record(args.get("device"), args.get("out"), frames);
    openni::OpenNI::shutdown();
  } catch (...) {
    spdlog::error("{}", rekon::currentExceptionLine());
    return 1;
  }
  return 0;
}
