#pragma once
// rekon-tracker: frames from the transport in, per-frame tracking results,
// DVO keyframes and odometry constraints out on the bus. Its pieces: the
// Inbox (the bus handlers), the TrackingWorker (tracks each frame), the
// History (publishes, and keeps what went out for replays) and the outputs.
#include "rekon/common/service.hpp"

namespace rekon::tracker {

// Runs until the frame source's end of stream has been tracked, or a stop is
// requested. Writes <out>/odometry.txt (world poses by odometry alone).
void runTrackerService(ServiceContext& ctx);

}  // namespace rekon::tracker
