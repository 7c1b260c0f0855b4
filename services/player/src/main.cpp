#include "rekon/common/error.hpp"
#include "rekon/player/player.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "player", "Publishes a TUM RGB-D dataset as frames on the rekon bus.",
      [](rekon::ArgParser& args) { args.option("dataset", "TUM RGB-D folder with camera.yaml (required)"); },
      [](rekon::ServiceContext& ctx) {
        if (ctx.args().get("dataset").empty()) throw rekon::Error("--dataset is required; see rekon-player --help");
        rekon::runPlayer(ctx, rekon::PlayerParams::fromConfig(ctx.config(), ctx.args().get("dataset")));
      });
}
