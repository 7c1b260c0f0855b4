#pragma once
// The dataset player: announces every frame of a TUM RGB-D dataset on the bus,
// as fast as its consumers acknowledge (`rate: max`), or at a multiple of the
// recorded rate. With `pacing: wait` no frame is ever dropped (the player
// falls behind the clock when its consumers are slower); with `pacing: live`
// it never waits and drops what the consumers are not ready for, newest
// first, exactly as a camera would.
#include <string>
#include <vector>

#include "rekon/common/service.hpp"

namespace rekon {

struct PlayerParams {
  std::string dataset;
  double rate = 0.0;  // multiple of the recorded rate; 0 = max (acknowledged)
  bool live = false;  // pacing: live (needs rate > 0)
  int live_in_flight = 2;
  std::vector<std::string> wait_for;
  double wait_timeout_s = 60.0;
  int max_frames = 0;
  int first_frame = 0;
  std::string camera;  // camera.yaml overriding the dataset's; "" = the dataset's
  int decode_threads = 0;  // frames decoded ahead on their own threads (0 = on the sending thread)
  std::string transport_mode = "auto";  // shm | lcm | auto
  std::string segment;
  int slots = 8;
  int max_width = 640;
  int max_height = 480;
  bool restarted = false;  // a new instance after a killed one: goes on where the consumers are

  static PlayerParams fromConfig(const Config& config, const std::string& dataset);
};

// Plays the whole dataset; returns when done or when ctx.stopRequested().
// Throws rekon::Error when a consumer stays silent beyond wait_timeout_s.
// A consumer restarted meanwhile (a new pid in its heartbeat) gets again what
// it missed: every frame from the resume point it announces on the bus (the
// mapper: after the last frame its keyframe store holds), so it works across
// hosts. After the end of stream the player stays until its consumers are
// done, so that one restarted late is served too. A restarted player goes on
// after the frames its consumers have, on the first instance's clock.
void runPlayer(ServiceContext& ctx, const PlayerParams& params);

}  // namespace rekon
