#include "rekon/common/error.hpp"
#include "rekon/player/player.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "player", "Publishes a TUM RGB-D dataset as frames on the rekon bus.",
      [](rekon::ArgParser& args) {
        args.option("dataset", "TUM RGB-D folder with camera.yaml (required)")
            .option("rate", "\"max\" (paced by acknowledgements) or a multiple of the recorded rate; overrides player.rate")
            .option("camera", "camera.yaml to use instead of the dataset's; overrides player.camera");
      },
      [](rekon::ServiceContext& ctx) {
        if (ctx.args().get("dataset").empty()) throw rekon::Error("--dataset is required; see rekon-player --help");
        rekon::Config config = ctx.config();
        if (ctx.args().has("rate")) config.set("player.rate", ctx.args().get("rate"));
        if (ctx.args().has("camera")) config.set("player.camera", ctx.args().get("camera"));
        rekon::runPlayer(ctx, rekon::PlayerParams::fromConfig(config, ctx.args().get("dataset")));
      });
}
