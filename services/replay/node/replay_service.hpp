#pragma once
// rekon-replay: for every frame the player announces, the tracked frame (and
// keyframe) the replay script gives, graph updates when due, and after the
// end of stream the final updates and done_t as the tracker and the optimiser
// send them (replay.hpp says what the script does).
#include "rekon/common/service.hpp"

namespace rekon::replay {

// --trajectory and --target options, frames from the bus; returns after the
// final updates, or at a stop request.
void runReplayService(ServiceContext& ctx);

}  // namespace rekon::replay
