#include "rekon/camera/fakenect_recording.hpp"

#include <spdlog/spdlog.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "rekon/common/error.hpp"

namespace rekon::camera {

namespace fs = std::filesystem;

namespace {

// What is wrong with one INDEX.txt entry, or "" when fakenect can play it.
std::string entryProblem(const fs::path& dir, const std::string& entry, size_t line) {
  char type = 0;
  double time = 0.0;
  unsigned tick = 0;
  if (std::sscanf(entry.c_str(), "%c-%lf-%u", &type, &time, &tick) != 3) {
    return "INDEX.txt line " + std::to_string(line) + " '" + entry +
           "' is not TYPE-TIME-TICK.EXT as record.c writes it";
  }
  const fs::path file = dir / entry;
  std::error_code ec;
  const auto size = static_cast<size_t>(fs::file_size(file, ec));
  if (ec) return entry + " (INDEX.txt line " + std::to_string(line) + ") cannot be read: " + ec.message();
  if (type != 'd' && type != 'r') {
    // fakenect reads any other file whole and ignores it unless it is empty.
    return size > 0 ? "" : entry + " is empty";
  }
  const bool depth = type == 'd';
  const std::string header = depth ? kFakenectDepthHeader : kFakenectColorHeader;
  const size_t want = header.size() + (depth ? kFakenectDepthBytes : kFakenectColorBytes);
  const std::string kind = depth ? "a depth frame" : "a color frame";
  const std::string layout = depth ? "640x480 16-bit values" : "640x480 RGB bytes";
  if (size != want) {
    return entry + " has " + std::to_string(size) + " bytes but " + kind + " has " + std::to_string(want) + " (the '" +
           header.substr(0, header.size() - 1) + "' header and " + layout + "): truncated or not written by record";
  }
  std::ifstream in(file, std::ios::binary);
  std::string start(header.size(), '\0');
  if (!in.read(start.data(), static_cast<std::streamsize>(start.size())) || start != header) {
    return entry + " does not start with record.c's header '" + header.substr(0, header.size() - 1) + "'";
  }
  return "";
}

}  // namespace

RecordingCheck checkRecording(const std::string& dir) {
  RecordingCheck check;
  check.dir = dir;
  std::ifstream index(fs::path(dir) / "INDEX.txt", std::ios::binary);
  if (!index) {
    throw Error("fakenect recording " + dir + ": no INDEX.txt; FAKENECT_PATH must name a folder written by record " +
                "(fakenect-record) or rekon-fakenect-write");
  }
  size_t line = 0;
  // fakenect stops at the first empty line (or the end of the file).
  for (std::string entry; std::getline(index, entry) && !entry.empty();) {
    ++line;
    const std::string problem = entryProblem(dir, entry, line);
    if (!problem.empty()) {
      check.bad = "fakenect recording " + dir + ": " + problem + "; the replay stopped before it";
      break;
    }
    ++check.playable;
    char type = 0;
    double time = 0;
    unsigned tick = 0;
    if (entry[0] == 'd' && std::sscanf(entry.c_str(), "%c-%lf-%u", &type, &time, &tick) == 3) check.depth_times[tick] = time;
    if (entry[0] == 'd') ++check.depth_frames;
    if (entry[0] == 'r') ++check.color_frames;
  }
  if (line == 0) throw Error("fakenect recording " + dir + ": INDEX.txt lists no frames");
  return check;
}

std::optional<RecordingCheck> checkReplayEnvironment(bool fakenect_loaded) {
  const char* path = std::getenv("FAKENECT_PATH");
  if (!fakenect_loaded) {
    if (path)
      spdlog::warn(
          "FAKENECT_PATH is set but the real libfreenect is loaded: ignored (the replay library is "
          "selected with LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect)");
    return std::nullopt;
  }
  if (!path || !*path) {
    throw Error(
        "freenect: the fakenect replay library is loaded (LD_LIBRARY_PATH) but FAKENECT_PATH is not set; "
        "set it to a recording folder, or drop the fakenect folder from LD_LIBRARY_PATH for a real Kinect");
  }
  RecordingCheck check = checkRecording(path);
  spdlog::info("fakenect recording {}: {} entries play ({} depth, {} color)", check.dir, check.playable,
               check.depth_frames, check.color_frames);
  if (!check.bad.empty()) spdlog::warn("{}", check.bad);
  return check;
}

}  // namespace rekon::camera
