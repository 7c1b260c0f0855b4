#pragma once
// rekon-viewer: listens to the run on the bus (mesh blocks, poses, keyframes,
// loop closures, heartbeats, stats), keeps it in a ViewerState and serves it
// to browsers. It only listens (and asks the mapper once for its whole mesh):
// a slow or absent browser never holds a service back.
#include "rekon/common/service.hpp"
#include "rekon/viewer/server.hpp"

namespace rekon::viewer {

struct ViewerParams {
  ServerOptions server;
  static ViewerParams fromConfig(const Config& config);
};

// Serves until a stop request (Ctrl-C, SIGTERM from rekon run, a shutdown message).
void runViewer(ServiceContext& ctx, const ViewerParams& params);

}  // namespace rekon::viewer
