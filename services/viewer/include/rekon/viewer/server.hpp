#pragma once
// The viewer's HTTP and WebSocket server (Boost.Beast, on one thread of its
// own). Routes: GET / (the page), a fixed list of static files (the page's
// script and style, three.js from the local install), /mesh.ply, /state.json,
// and the WebSocket /ws: the full state on connect, then every Update.
// Nothing a browser does can slow the caller of ViewerState: updates are
// queued per client with coalescing (newest message per key), and a client
// whose queue outgrows max_client_bytes, or whose write does not finish in
// write_timeout_s, is dropped. Everything a peer sends is bounded (header
// bytes, header time, no request bodies, WebSocket message size, clients).
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "rekon/viewer/viewer_state.hpp"

namespace rekon::viewer {

struct ServerOptions {
  std::string bind = "127.0.0.1";
  int port = 8090;                             // 0: any free port (port() says which)
  int max_clients = 64;                        // open connections of any kind; more are closed at once
  size_t max_client_bytes = 32u << 20;         // queued for one WebSocket client; beyond: dropped
  double write_timeout_s = 10.0;               // one WebSocket write; longer: the client is dropped
  double header_timeout_s = 5.0;               // a request's header must arrive within this
  size_t max_header_bytes = 8192;              // larger: 431 and close
  size_t max_ws_message_bytes = 4096;          // a larger incoming WebSocket message closes the connection
  std::string three_dir = "/usr/share/javascript/three";  // Debian's libjs-three

  // Throws rekon::Error naming the key for a value out of range.
  void validate() const;
};

class Server {
 public:
  // Binds at once (throws rekon::Error naming the address when it cannot);
  // serves from start() until stop() or destruction. `state` must outlive it.
  Server(ViewerState& state, const ServerOptions& options);
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  void start();
  void stop();

  int port() const;
  std::string url() const;  // http://ADDRESS:PORT/

  struct Counts {
    size_t connections = 0, websocket_clients = 0;
    uint64_t clients_dropped = 0;  // for their queue or a write timeout
    uint64_t requests_rejected = 0;  // 4xx answers and connections closed for bad input
    uint64_t messages_sent = 0, bytes_sent = 0, updates_coalesced = 0;
  };
  Counts counts() const;

  struct Impl;  // server.cpp: the io thread, its connections and their Beast types

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace rekon::viewer
