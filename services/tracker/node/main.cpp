// rekon-tracker: the DVO tracking service (see tracker_service.hpp).
#include "tracker_service.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "tracker",
      "Tracks every frame from the transport against its DVO keyframe and publishes tracked frames, keyframes "
      "and odometry constraints on the rekon bus.",
      nullptr, [](rekon::ServiceContext& ctx) { rekon::tracker::runTrackerService(ctx); });
}
