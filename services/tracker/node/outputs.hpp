#pragma once
// What the tracker leaves at the end: its stats (written by the service
// context), <out>/odometry.txt (world poses by odometry alone),
// <out>/tracker_timing.csv (ms per frame) and a summary in the log; when it
// only localised in a session (session.localise_only), <out>/trajectory.txt:
// the frames placed in the session's map (TUM), lost ones left out.
#include <cstdint>

#include "rekon/common/service.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "tracking_worker.hpp"

namespace rekon::tracker {

void writeOutputs(ServiceContext& ctx, const TrackingTotals& totals, int64_t frames_sent_again, double ack_held_s,
                  const LoopClosureStats& loops, const KeyframeCacheStats& keyframes, bool localise_only);

}  // namespace rekon::tracker
