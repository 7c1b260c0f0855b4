#pragma once
// A recording for Debian's fakenect replay library (libfreenect 0.5's
// fakenect/fakenect.c and record.c): INDEX.txt lists one file per line,
// `d-<time %f>-<tick %u>.pgm` (record.c's "P5 640 480 65535\n" header and
// 640x480 little-endian 11-bit values), `r-...ppm` ("P6 640 480 255\n" and
// RGB bytes) and `a-...dump` (accelerometer state); an empty line or the end
// of the file ends it. That fakenect exits the process on a missing file and
// reads past the end of a short one, so a recording is checked before it
// plays and only the entries before the first bad one are played.
#include <cstdint>
#include <map>
#include <optional>
#include <string>

namespace rekon::camera {

inline constexpr char kFakenectDepthHeader[] = "P5 640 480 65535\n";
inline constexpr char kFakenectColorHeader[] = "P6 640 480 255\n";
inline constexpr size_t kFakenectDepthBytes = 640 * 480 * 2;
inline constexpr size_t kFakenectColorBytes = 640 * 480 * 3;

struct RecordingCheck {
  std::string dir;
  size_t playable = 0;                        // INDEX.txt entries before the first bad one (all when none is bad)
  size_t depth_frames = 0, color_frames = 0;  // among the playable entries
  std::string bad;  // one line naming the first bad entry and why; "" when every entry is good
  // The recording's own clock: each playable depth entry's recorded time
  // (seconds) by its device tick, which fakenect hands to the callback.
  std::map<uint32_t, double> depth_times;
};

// Throws rekon::Error (one line naming the folder) when DIR/INDEX.txt is
// missing or lists nothing.
RecordingCheck checkRecording(const std::string& dir);

// What FAKENECT_PATH asks for: the checked recording when the fakenect
// library is the one loaded; nullopt for a real device (FAKENECT_PATH set
// beside the real library is ignored with a warning). Throws rekon::Error
// when fakenect is loaded without FAKENECT_PATH (it would exit the process).
std::optional<RecordingCheck> checkReplayEnvironment(bool fakenect_loaded);

}  // namespace rekon::camera
