#include "viewer_service.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <thread>

#include "inbox.hpp"

namespace rekon::viewer {

ViewerParams ViewerParams::fromConfig(const Config& config) {
  ViewerParams p;
  ServerOptions& s = p.server;
  s.bind = config.getString("viewer.bind");
  s.port = config.getInt("viewer.port");
  s.max_clients = config.getInt("viewer.max_clients");
  const int mb = config.getInt("viewer.max_client_mb");
  s.max_client_bytes = mb > 0 ? static_cast<size_t>(mb) << 20 : 0;
  s.write_timeout_s = config.getDouble("viewer.write_timeout_s");
  s.header_timeout_s = config.getDouble("viewer.header_timeout_s");
  s.three_dir = config.getString("viewer.three_dir");
  s.validate();
  return p;
}

void runViewer(ServiceContext& ctx, const ViewerParams& params) {
  ViewerState state;
  Server server(state, params.server);
  StopThreadsOnExit stop_threads(ctx);  // after `state`: the bus handlers use it
  subscribeViewer(ctx.bus(), state, ctx.name());
  server.start();
  spdlog::info("viewer: {}", server.url());
  ctx.setState("running");
  while (!ctx.stopRequested()) {
    ctx.setLive("clients", static_cast<double>(server.counts().websocket_clients));
    ctx.setLive("blocks", static_cast<double>(state.counts().blocks));
    state.markSilent(ctx.lifecycle().silence_s);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ctx.setState("finishing");
  server.stop();
  const Server::Counts c = server.counts();
  const ViewerState::Counts s = state.counts();
  ctx.stats()
      .set("blocks", s.blocks)
      .set("vertices", s.vertices)
      .set("triangles", s.triangles)
      .set("block_updates", static_cast<long long>(s.block_updates))
      .set("receive_latency_samples", static_cast<long long>(s.receive_latency_samples))
      .set("receive_latency_ms_p50", s.receive_latency_ms_p50)
      .set("receive_latency_ms_p95", s.receive_latency_ms_p95)
      .set("messages_sent", static_cast<long long>(c.messages_sent))
      .set("bytes_sent", static_cast<long long>(c.bytes_sent))
      .set("updates_coalesced", static_cast<long long>(c.updates_coalesced))
      .set("clients_dropped", static_cast<long long>(c.clients_dropped))
      .set("requests_rejected", static_cast<long long>(c.requests_rejected));
}

}  // namespace rekon::viewer
