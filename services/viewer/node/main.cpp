// rekon-viewer: the run on the bus as a live web page.
#include "viewer_service.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "viewer",
      "Serves a live view of the run on the bus (mesh, camera, keyframes, loop closures, status) as a web page "
      "over HTTP and WebSocket. The page has no authentication: bind other interfaces than 127.0.0.1 only on purpose.",
      [](rekon::ArgParser& args) {
        args.option("port", "TCP port (0: any free one; the URL is logged); overrides viewer.port")
            .option("bind", "address to listen on; overrides viewer.bind");
      },
      [](rekon::ServiceContext& ctx) {
        rekon::Config config = ctx.config();
        for (const char* key : {"port", "bind"}) {
          if (ctx.args().has(key)) config.set(std::string("viewer.") + key, ctx.args().get(key));
        }
        rekon::viewer::runViewer(ctx, rekon::viewer::ViewerParams::fromConfig(config));
      });
}
