#pragma once
// rekon-optimiser: keyframes, constraints and tracked frames in; a graph
// update after every background optimisation out; at the tracker's done, a
// final optimisation, the final update, <out>/trajectory.txt and done. Its
// pieces: the Inbox (the bus handlers), the GraphWorker (the pose graph fed
// from it), recovery (replays from the tracker) and the outputs.
#include "rekon/common/service.hpp"

namespace rekon::optimiser {

// Returns after the final step (the tracker's done_t, or a stop request).
void runOptimiserService(ServiceContext& ctx);

}  // namespace rekon::optimiser
