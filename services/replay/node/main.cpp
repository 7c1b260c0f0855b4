// rekon-replay: a frontend that replays given poses in place of the tracker and the optimiser.
#include "replay_service.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "replay",
      "Publishes a trajectory file's poses as tracked frames with DVO-style keyframes for the frames rekon-player "
      "announces, then graph updates that move the keyframes to a target trajectory (run it beside rekon-player "
      "--set player.wait_for=[replay,mapper] and rekon-mapper).",
      [](rekon::ArgParser& args) {
        args.option("trajectory", "TUM trajectory published as the tracked poses (required)")
            .option("target", "TUM trajectory the graph updates move the keyframes to (required)")
            .option("update-every", "a graph update after this many new keyframes during the stream (0 = none)", "3")
            .option("stream-alpha", "fraction of the way to the target by the end of the stream", "0.5")
            .option("final-updates", "graph updates after the stream, the last at the target", "4")
            .option("gap-ms", "pause between the final updates", "100")
            .option("odometry-sigma", "T,R: be the tracker only: odometry constraints between consecutive keyframes "
                                      "with these standard deviations (metres, radians) for rekon-optimiser, no graph "
                                      "updates (--target is then not needed)");
      },
      [](rekon::ServiceContext& ctx) { rekon::replay::runReplayService(ctx); });
}
