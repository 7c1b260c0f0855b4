#pragma once
// The viewer's bus subscriptions: every message becomes a ViewerState call,
// validated on the way (a NaN pose or an unusable update is dropped with one line).
#include "rekon/common/bus.hpp"
#include "rekon/viewer/viewer_state.hpp"

namespace rekon::viewer {

// Subscribes `state` to the run's channels on `bus` (handlers run on its thread).
// `service` is this viewer's name (its mesh requests say who asks).
void subscribeViewer(Bus& bus, ViewerState& state, const std::string& service);

}  // namespace rekon::viewer
