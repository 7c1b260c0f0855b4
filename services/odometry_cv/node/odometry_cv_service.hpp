#pragma once
// rekon-odometry_cv's bus wiring: frames in; keyframes, tracked frames, graph
// updates (the chained odometry: no back end), acknowledgements and done_t
// out, as messages/FRONTEND.md asks; trajectory.txt at the end.
#include "rekon/common/service.hpp"

namespace rekon::odometry_cv {

void runOdometryCvService(ServiceContext& ctx);

}  // namespace rekon::odometry_cv
