// The viewer's server against real sockets on 127.0.0.1 (a free port per
// test): hostile HTTP and WebSocket input is rejected within its bounds and
// the server answers afterwards; many browsers get the full state; a browser
// that stops reading is dropped while the others keep getting updates.
#include <gtest/gtest.h>

#include <sys/socket.h>

#include <algorithm>
#include <iostream>
#include <atomic>
#include <memory>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/viewer/protocol.hpp"
#include "rekon/viewer/server.hpp"
#include "viewer_test_support.hpp"

namespace rekon::viewer {
namespace {

using test::RawClient;
using test::secondsSince;
using test::statusOf;
using test::syntheticBlock;
using Clock = std::chrono::steady_clock;

// Short limits so that the tests are quick; each test says which one it checks.
ServerOptions testOptions() {
  ServerOptions o;
  o.port = 0;
  o.header_timeout_s = 1.0;
  o.write_timeout_s = 1.0;
  o.max_client_bytes = 4u << 20;
  return o;
}

class ViewerServer : public ::testing::Test {
 protected:
  void SetUp() override { start(testOptions()); }
  void start(const ServerOptions& o) {
    server_.reset();
    server_ = std::make_unique<Server>(state_, o);
    server_->start();
    port_ = server_->port();
  }
  void expectStillServing() {
    const std::string r = test::httpGet(port_, "/state.json");
    EXPECT_EQ(statusOf(r), 200) << r.substr(0, 200);
    EXPECT_NE(r.find("\"blocks\":"), std::string::npos);
  }
  ViewerState state_;
  std::unique_ptr<Server> server_;
  int port_ = 0;
};

TEST_F(ViewerServer, ServesThePageItsFilesAndTheState) {
  const std::string page = test::httpGet(port_, "/");
  EXPECT_EQ(statusOf(page), 200);
  EXPECT_NE(page.find("<script src=\"/app.js\">"), std::string::npos);
  EXPECT_EQ(statusOf(test::httpGet(port_, "/app.js")), 200);
  EXPECT_EQ(statusOf(test::httpGet(port_, "/style.css")), 200);
  EXPECT_EQ(statusOf(test::httpGet(port_, "/index.html?reload=1")), 200);
  state_.applyBlock(syntheticBlock({0, 0, 0}, 1, 6));
  const std::string ply = test::httpGet(port_, "/mesh.ply");
  EXPECT_EQ(statusOf(ply), 200);
  EXPECT_NE(ply.find("element vertex 8\n"), std::string::npos);
  EXPECT_NE(ply.find("element face 6\n"), std::string::npos);
}

TEST_F(ViewerServer, PathsOutsideTheWhitelistAre404) {
  for (const char* target : {"/../../../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd", "/..%2f..%2fetc%2fpasswd",
                             "//etc/passwd", "/etc/passwd", "/three.min.js/../../etc/passwd", "/app.js%00.png",
                             "http://127.0.0.1/etc/passwd", "/usr/share/javascript/three/three.min.js", "*"}) {
    const std::string r = test::httpGet(port_, target);
    EXPECT_EQ(statusOf(r), 404) << target << ": " << r.substr(0, 100);
    EXPECT_EQ(r.find("root:"), std::string::npos) << target;
  }
  expectStillServing();
}

TEST_F(ViewerServer, OversizedHeaderIsAnsweredWith431) {
  RawClient c(port_);
  const auto start = Clock::now();
  c.send("GET / HTTP/1.1\r\nHost: x\r\nX-Big: " + std::string(20000, 'a') + "\r\n\r\n");
  const std::string r = c.readUntilClosed(5.0);
  EXPECT_EQ(statusOf(r), 431) << r.substr(0, 100);
  EXPECT_LT(secondsSince(start), 1.0);  // answered at the 8 KB limit, not at a timeout
  expectStillServing();
}

TEST_F(ViewerServer, RequestBodiesAndOtherMethodsAreRefused) {
  {
    RawClient c(port_);
    c.send("GET / HTTP/1.1\r\nHost: x\r\nContent-Length: 100000\r\n\r\n" + std::string(1000, 'x'));
    EXPECT_EQ(statusOf(c.readUntilClosed(3.0)), 413);
  }
  {
    RawClient c(port_);
    c.send("DELETE /mesh.ply HTTP/1.1\r\nHost: x\r\n\r\n");
    EXPECT_EQ(statusOf(c.readUntilClosed(3.0)), 405);
  }
  {
    RawClient c(port_);
    c.send("\x16\x03\x01\x02\x00garbage that is not HTTP\r\n\r\n");
    EXPECT_EQ(statusOf(c.readUntilClosed(3.0)), 400);
  }
  expectStillServing();
}

// Slowloris: one header byte every 200 ms never completes a request; the
// connection is closed at header_timeout_s (1 s here), not kept open.
TEST_F(ViewerServer, TricklingHeaderIsClosedAtTheHeaderTimeout) {
  RawClient c(port_);
  const auto start = Clock::now();
  const std::string request = "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + std::string(100, 'a');
  bool closed = false;
  for (char ch : request) {
    if (!c.send(std::string(1, ch)) || c.closedWithin(0.2)) {
      closed = true;
      break;
    }
  }
  const double t = secondsSince(start);
  EXPECT_TRUE(closed);
  EXPECT_GE(t, 0.9);  // not before the timeout
  EXPECT_LT(t, 2.0);  // the 1 s timeout plus one 200 ms trickle step and scheduling margin
  expectStillServing();
}

std::string wsHandshake() {
  return "GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
         "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";
}

// Reads the handshake's answer (and whatever the server sends first) without waiting for a close.
std::string readSome(RawClient& c, double seconds) {
  std::string out;
  const auto start = Clock::now();
  char buf[65536];
  while (secondsSince(start) < seconds) {
    const ssize_t n = ::recv(c.fd(), buf, sizeof(buf), MSG_DONTWAIT);
    if (n > 0) out.append(buf, static_cast<size_t>(n));
    else std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return out;
}

TEST_F(ViewerServer, MalformedWebSocketFramesCloseTheConnection) {
  // An unmasked client frame (RFC 6455 requires masking), a reserved opcode, and a reserved bit.
  for (const std::string& frame : {std::string("\x81\x05hello", 7), std::string("\x83\x80\x01\x02\x03\x04", 6),
                                  std::string("\xF1\x80\x01\x02\x03\x04", 6)}) {
    RawClient c(port_);
    c.send(wsHandshake());
    EXPECT_EQ(statusOf(readSome(c, 0.3)), 101);
    c.send(frame);
    EXPECT_TRUE(c.closedWithin(2.0));
  }
  expectStillServing();
}

TEST_F(ViewerServer, OneMegabyteWebSocketMessageClosesTheConnection) {
  RawClient c(port_);
  c.send(wsHandshake());
  EXPECT_EQ(statusOf(readSome(c, 0.3)), 101);
  // A masked binary frame that declares 1 MiB (64-bit length): over the 4 KB limit from its header on.
  std::string header("\x82\xFF", 2);
  for (int shift = 56; shift >= 0; shift -= 8) header.push_back(static_cast<char>((uint64_t{1} << 20) >> shift & 0xFF));
  header += std::string("\x01\x02\x03\x04", 4);
  const auto start = Clock::now();
  c.send(header + std::string(64 * 1024, 'x'));  // the server need not read the rest to refuse it
  EXPECT_TRUE(c.closedWithin(2.0));
  EXPECT_LT(secondsSince(start), 2.0);
  expectStillServing();
}

TEST_F(ViewerServer, ConnectionsBeyondTheCapAreClosedAndTheServerRecovers) {
  std::vector<std::unique_ptr<RawClient>> held;
  for (int i = 0; i < 64; ++i) held.push_back(std::make_unique<RawClient>(port_));  // idle, inside the cap
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  int refused = 0;
  for (int i = 0; i < 100; ++i) {
    RawClient extra(port_);
    refused += extra.closedWithin(0.5);
  }
  EXPECT_EQ(refused, 100);
  EXPECT_EQ(server_->counts().connections, 64u);
  held.clear();  // idle ones also end at the header timeout; closing them frees the slots now
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  expectStillServing();
}

TEST_F(ViewerServer, TwentyClientsAtOnceAllGetTheFullStateThenUpdates) {
  for (int i = 0; i < 200; ++i) state_.applyBlock(syntheticBlock({i % 20, i / 20, 0}, 1));
  state_.heartbeat("mapper", 1, "h", "running", 10);
  std::vector<std::unique_ptr<test::WsClient>> clients;
  for (int i = 0; i < 20; ++i) clients.push_back(std::make_unique<test::WsClient>(port_));
  for (auto& c : clients) {
    while (c->blocks() < 200 && c->readOne(5.0)) {
    }
    EXPECT_EQ(c->blocks(), 200);
    EXPECT_GE(c->texts(), 4);  // status, keyframes, edges, trajectory
  }
  state_.applyBlock(syntheticBlock({3, 3, 0}, 2));
  for (auto& c : clients) {
    while (c->version({3, 3, 0}) != 2 && c->readOne(5.0)) {
    }
    EXPECT_EQ(c->version({3, 3, 0}), 2);
  }
  EXPECT_EQ(server_->counts().websocket_clients, 20u);
}

// Each page's newest report is listed in /state.json's "clients"; a hostile
// one leaves that JSON intact.
TEST_F(ViewerServer, PageReportsAppearInTheStateAndHostileOnesAreSanitised) {
  test::WsClient page(port_), hostile(port_);
  ASSERT_TRUE(page.sendText(R"({"type":"report","blocks":7,"latency_ms_p95":120})"));
  ASSERT_TRUE(hostile.sendText(R"({"type":"report","blocks":"1}]}","vertices":Infinity})"));
  std::string state;
  const auto start = Clock::now();
  while (state.find(R"("blocks":7,"latency_ms_p95":120})") == std::string::npos && secondsSince(start) < 5) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    state = test::httpGet(port_, "/state.json");
  }
  EXPECT_NE(state.find(R"("clients":[)"), std::string::npos) << state;
  EXPECT_NE(state.find(R"({"blocks":7,"latency_ms_p95":120})"), std::string::npos) << state;
  EXPECT_EQ(state.find("Infinity"), std::string::npos) << state;
  EXPECT_EQ(state.find("1}]}"), std::string::npos) << state;
  EXPECT_EQ(state.back(), '}');
}

// A browser that never reads: its socket fills, its next write times out
// (write_timeout_s, 4 s here) and it is dropped; the publisher never waits
// and a reading browser gets every block's newest version meanwhile.
TEST_F(ViewerServer, ClientThatNeverReadsIsDroppedOthersKeepUpdating) {
  ServerOptions options = testOptions();
  options.write_timeout_s = 4.0;  // a publisher that waited for the browser would wait this long
  start(options);
  RawClient stalled(port_, 4096);
  stalled.send(wsHandshake());  // and never reads again
  test::WsClient reader(port_);
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  std::atomic<bool> done{false};
  double slowest_apply_ms = 0;
  std::thread publisher([&] {
    // 50 blocks of 2000 triangles (about 57 KB each), re-versioned for 8 s: far more than the stalled socket holds.
    for (int64_t v = 1; !done.load(); ++v) {
      for (int i = 0; i < 50; ++i) {
        const auto t0 = Clock::now();
        state_.applyBlock(syntheticBlock({i, 0, 0}, v, 2000));
        slowest_apply_ms = std::max(slowest_apply_ms, secondsSince(t0) * 1000);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  });
  const auto start = Clock::now();
  while (secondsSince(start) < 8.0) reader.readOne(0.5);
  done = true;
  publisher.join();
  EXPECT_EQ(server_->counts().clients_dropped, 1u);
  EXPECT_EQ(server_->counts().websocket_clients, 1u);
  // The reader drains to the newest version of every block.
  const int64_t newest = [&] {
    int64_t v = 0;
    for (const Update& u : state_.snapshot()) {
      if (u.binary) v = std::max(v, decodeBlockMessage(*u.payload)->version);
    }
    return v;
  }();
  while (reader.version({49, 0, 0}) != newest && reader.readOne(2.0)) {
  }
  EXPECT_EQ(reader.version({49, 0, 0}), newest);
  EXPECT_GT(server_->counts().updates_coalesced, 0u);
  // Measured 3.8-4.5 ms (encoding a 57 KB block under the lock), but up to
  // 212 ms when the thread was preempted (2 of 6 runs beside CPU hogs; 50 ms
  // was the bound then). A wait for the browser lasts the write timeout:
  // 1 s is a quarter of it and above the longest stall of a starved process
  // measured on this machine (0.54 s, a player's decode under load 12).
  EXPECT_LT(slowest_apply_ms, 1000.0) << "the publisher waited for a browser";
  const Server::Counts c = server_->counts();
  std::cout << "slowest applyBlock " << slowest_apply_ms << " ms; sent " << c.messages_sent << " messages, "
            << (c.bytes_sent >> 20) << " MiB; coalesced " << c.updates_coalesced << "\n";
}

TEST(ViewerServerOptions, BadSettingsAreOneLineErrors) {
  ViewerState state;
  ServerOptions o;
  o.bind = "localhost:80";
  EXPECT_THROW(Server(state, o), Error);
  o = ServerOptions{};
  o.port = 70000;
  EXPECT_THROW(Server(state, o), Error);
  o = ServerOptions{};
  o.port = 0;
  Server first(state, o);
  o.port = first.port();  // taken
  EXPECT_THROW(Server(state, o), Error);
}

}  // namespace
}  // namespace rekon::viewer
