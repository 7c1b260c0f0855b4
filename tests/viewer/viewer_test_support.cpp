#include "viewer_test_support.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <boost/asio.hpp>
#include <array>
#include <cmath>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>
#include <map>
#include <stdexcept>

#include "rekon/viewer/protocol.hpp"

namespace rekon::viewer::test {

namespace beast = boost::beast;
namespace net = boost::asio;
using tcp = net::ip::tcp;

double secondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

BlockMesh syntheticBlock(BlockKey key, int64_t version, int triangles) {
  BlockMesh b;
  b.x = key.x;
  b.y = key.y;
  b.z = key.z;
  b.version = version;
  const float s = 0.08f, x0 = static_cast<float>(key.x) * s, y0 = static_cast<float>(key.y) * s,
              z0 = static_cast<float>(key.z) * s;
  // A fan on the block's z face: vertex 0 at the centre, the rest around it.
  b.vertices.emplace_back(x0 + s / 2, y0 + s / 2, z0);
  for (int i = 0; i <= triangles; ++i) {
    const float a = 6.2831853f * static_cast<float>(i) / static_cast<float>(triangles);
    b.vertices.emplace_back(x0 + s / 2 + 0.5f * s * std::cos(a), y0 + s / 2 + 0.5f * s * std::sin(a), z0);
  }
  const std::array<uint8_t, 3> color{static_cast<uint8_t>(60 + 20 * (key.x & 7)), static_cast<uint8_t>(60 + 20 * (key.y & 7)),
                                     static_cast<uint8_t>(120 + version % 100)};
  b.colors.assign(b.vertices.size(), color);
  for (int i = 0; i < triangles; ++i) b.triangles.emplace_back(0, i + 1, i + 2);
  return b;
}

RawClient::RawClient(int port, int receive_buffer_bytes) {
  fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
  if (receive_buffer_bytes > 0) setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &receive_buffer_bytes, sizeof(int));
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (fd_ < 0 || ::connect(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
    throw std::runtime_error("cannot connect to 127.0.0.1:" + std::to_string(port));
  }
}

RawClient::~RawClient() {
  if (fd_ >= 0) ::close(fd_);
}

bool RawClient::send(const std::string& bytes) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::send(fd_, bytes.data() + done, bytes.size() - done, MSG_NOSIGNAL);
    if (n <= 0) return false;
    done += static_cast<size_t>(n);
  }
  return true;
}

std::string RawClient::readUntilClosed(double timeout_s) {
  std::string out;
  const auto start = std::chrono::steady_clock::now();
  char buf[65536];
  while (secondsSince(start) < timeout_s) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    const ssize_t n = ::recv(fd_, buf, sizeof(buf), 0);
    if (n <= 0) break;
    out.append(buf, static_cast<size_t>(n));
  }
  return out;
}

bool RawClient::closedWithin(double timeout_s) {
  const auto start = std::chrono::steady_clock::now();
  char buf[65536];
  while (secondsSince(start) < timeout_s) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    if (::recv(fd_, buf, sizeof(buf), 0) <= 0) return true;
  }
  return false;
}

int statusOf(const std::string& response) {
  if (response.rfind("HTTP/1.1 ", 0) != 0 || response.size() < 12) return 0;
  return std::atoi(response.substr(9, 3).c_str());
}

std::string httpGet(int port, const std::string& target, double timeout_s) {
  RawClient c(port);
  c.send("GET " + target + " HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  return c.readUntilClosed(timeout_s);
}

struct WsClient::Impl {
  net::io_context ioc;
  beast::websocket::stream<tcp::socket> ws{ioc};
  beast::flat_buffer buffer;
  std::map<BlockKey, int64_t> versions;
};

WsClient::WsClient(int port) : impl_(new Impl) {
  impl_->ws.next_layer().connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), static_cast<unsigned short>(port)));
  impl_->ws.handshake("127.0.0.1", "/ws");
}

WsClient::~WsClient() {
  beast::error_code ec;
  impl_->ws.next_layer().close(ec);
  delete impl_;
}

bool WsClient::readOne(double timeout_s) {
  // A receive timeout on the socket: the synchronous read fails instead of waiting forever.
  const int fd = impl_->ws.next_layer().native_handle();
  timeval tv{static_cast<time_t>(timeout_s), static_cast<suseconds_t>((timeout_s - static_cast<int>(timeout_s)) * 1e6)};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  beast::error_code ec;
  impl_->buffer.clear();
  impl_->ws.read(impl_->buffer, ec);
  if (ec) return false;
  if (impl_->ws.got_binary()) {
    const std::string bytes = beast::buffers_to_string(impl_->buffer.data());
    if (const auto b = decodeBlockMessage(bytes)) impl_->versions[BlockKey{b->x, b->y, b->z}] = b->version;
    ++blocks_;
  } else {
    ++texts_;
  }
  return true;
}

bool WsClient::sendText(const std::string& text) {
  beast::error_code ec;
  impl_->ws.text(true);
  impl_->ws.write(net::buffer(text), ec);
  return !ec;
}

int64_t WsClient::version(const BlockKey& key) const {
  const auto it = impl_->versions.find(key);
  return it == impl_->versions.end() ? -1 : it->second;
}

}  // namespace rekon::viewer::test
