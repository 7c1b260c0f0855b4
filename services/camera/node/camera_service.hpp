#pragma once
// rekon-camera's work: opens the device, announces its frames on the bus
// through the live outlet (newest wins, never waits), records every captured
// frame when asked, and ends the stream when the recording ends, the device
// is lost, or the run stops.
#include <string>
#include <vector>

#include "rekon/camera/source.hpp"
#include "rekon/common/service.hpp"

namespace rekon::camera {

struct CameraParams {
  std::string device;  // openni2[:URI] | freenect[:INDEX]
  SourceOptions source;
  std::string record;  // TUM folder to record into; "" = none
  int record_queue = 64;
  std::vector<std::string> wait_for;
  double wait_timeout_s = 60.0;
  int max_frames = 0;  // 0 = until the device ends or the run stops
  double reconnect_timeout_s = 10.0;  // a lost device is reopened for this long (0: never)
  double reconnect_wait_s = 0.25;     // first wait before reopening; doubled each attempt, to 8 times this
  bool restarted = false;             // a new process after a killed one: ids go on after the consumers' newest
  std::string transport_mode = "auto";
  std::string segment;
  int slots = 8;
  int max_width = 640;
  int max_height = 480;
  int in_flight = 2;

  static CameraParams fromConfig(const Config& config);
};

void runCamera(ServiceContext& ctx, const CameraParams& params);

}  // namespace rekon::camera
