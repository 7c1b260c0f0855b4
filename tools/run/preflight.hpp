#pragma once
// What `rekon run` checks before it starts or creates anything (issue 27: a
// bad value, an empty dataset or an unknown camera driver used to be found
// after every service had started, and left an empty run behind). Each
// check throws rekon::Error: one line naming the thing and the fix.
#include <string>

#include "rekon/common/config.hpp"

namespace rekon {

// Every key's value has its default's type (a number stays a number, true
// or false stays a boolean), and each service's own settings parser accepts
// the configuration (ranges: mapper.kappa >= 1, volume.voxel_size > 0, ...).
// With a dataset, the player's settings too.
void checkConfigValues(const Config& config, const std::string& dataset);

struct DatasetSpan {
  long long frames = 0;
  double seconds = 0;  // first to last timestamp
};
// A TUM-layout dataset with camera.yaml and at least one frame.
DatasetSpan checkDataset(const std::string& dir);

// A camera spec names a driver rekon-camera has, openni2[:URI|FILE.oni] or
// freenect[:INDEX], and a device that driver sees now (or a recording that
// exists); or realsense[:SERIAL], checked by checkRealSense.
void checkCameraSpec(const std::string& spec, const std::string& playback, const Config& config);

// realsense[:SERIAL] (rekon-realsense): the camera Intel's SDK sees now, or
// the --playback recording with depth and color at realsense.width/height/fps,
// each refusal rekon-realsense's own line (rekon-realsense --check).
void checkRealSense(const std::string& spec, const std::string& playback, const Config& config);

// The viewer can listen on viewer.bind:viewer.port (a busy port used to fail
// the viewer after every service had started).
void checkViewerPort(const Config& config);


// The files a run writes at the top of its --out folder.
bool isRunOutput(const std::string& file_name);

// An --out folder that holds an earlier run (its config.yaml or stats.json)
// is refused, unless `force`: then that run's files are removed first, so
// that nothing of it is listed as this run's.
void claimRunFolder(const std::string& out, bool force);

}  // namespace rekon
