#pragma once
// Records every captured frame as a TUM RGB-D dataset (rgb/*.ppm and
// depth/*.pgm, uncompressed so a 30 Hz camera fits on one core;
// rgb.txt, depth.txt, camera.yaml), on its own thread so that capture never
// waits for the disk: push() only queues, and a frame that finds the queue
// full is counted as dropped, never silently lost. The index files are
// flushed after every frame, so a recording cut short still opens with
// `rekon run --dataset DIR`.
#include <cstdint>
#include <memory>
#include <string>

#include "rekon/common/camera.hpp"
#include "rekon/common/rgbd_frame.hpp"

namespace rekon::camera {

// Throws rekon::Error naming `dir` when it already holds a recording (rgb.txt
// or depth.txt): a recording never overwrites one. rekon run checks it before
// anything starts; the Recorder again when it creates the folder.
void requireNoRecording(const std::string& dir);

class Recorder {
 public:
  // Creates `dir` (which must not hold a dataset already: nothing is ever
  // overwritten) with its camera.yaml; throws rekon::Error naming it.
  Recorder(const std::string& dir, const Intrinsics& k, int max_queued);
  ~Recorder();  // writes what is queued, then stops
  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;

  // Never blocks. The frame's images are shared, not copied: the caller
  // must not write into them afterwards.
  void push(const RgbdFrame& frame);
  // Writes what is queued and stops the thread; the counts are final after it.
  void close();

  int64_t written() const;
  int64_t dropped() const;  // the queue was full (the disk did not keep up)
  int64_t failed() const;   // a write failed (logged once with the reason)

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace rekon::camera
