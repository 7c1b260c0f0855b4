// rekon-optimiser: the pose-graph optimisation service (see optimiser_service.hpp).
#include "optimiser_service.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "optimiser",
      "Optimises the keyframe pose graph from the tracker's keyframes and constraints in the background, publishes "
      "graph updates, and writes every tracked frame's optimised pose to trajectory.txt at the end.",
      nullptr, [](rekon::ServiceContext& ctx) { rekon::optimiser::runOptimiserService(ctx); });
}
