#pragma once
// What the viewer tests share: synthetic blocks, a raw TCP client for
// hostile input, and a WebSocket client (Beast, synchronous) that counts what
// the server sends.
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

#include "rekon/viewer/viewer_state.hpp"

namespace rekon::viewer::test {

// A block of `triangles` triangles (a fan in the block's unit cube, 8 cm blocks), colored by its key.
BlockMesh syntheticBlock(BlockKey key, int64_t version, int triangles = 20);

// A connected TCP socket to 127.0.0.1:port (throws on failure); closed by the destructor.
class RawClient {
 public:
  explicit RawClient(int port, int receive_buffer_bytes = 0);
  ~RawClient();
  RawClient(const RawClient&) = delete;
  RawClient& operator=(const RawClient&) = delete;

  // False when the peer has closed (or reset) the connection.
  bool send(const std::string& bytes);
  // Everything until the peer closes or `timeout_s` passes.
  std::string readUntilClosed(double timeout_s);
  // True when the peer closed within `timeout_s` (bytes it sent before are discarded).
  bool closedWithin(double timeout_s);
  int fd() const { return fd_; }

 private:
  int fd_ = -1;
};

// "HTTP/1.1 200 OK ..." -> 200; 0 when there is no status line.
int statusOf(const std::string& response);
// One GET with a fresh connection: the whole response.
std::string httpGet(int port, const std::string& target, double timeout_s = 5.0);

// A WebSocket client of /ws on 127.0.0.1:port that counts messages.
class WsClient {
 public:
  explicit WsClient(int port);
  ~WsClient();
  // Reads one message; false on close, error or timeout.
  bool readOne(double timeout_s);
  // Sends one text message; false on error.
  bool sendText(const std::string& text);
  int blocks() const { return blocks_; }
  int texts() const { return texts_; }
  // The newest version received of block `key` (-1: none).
  int64_t version(const BlockKey& key) const;

 private:
  struct Impl;
  Impl* impl_;
  int blocks_ = 0, texts_ = 0;
};

double secondsSince(std::chrono::steady_clock::time_point t);

}  // namespace rekon::viewer::test
