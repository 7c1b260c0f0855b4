// The viewer's server on Boost.Beast: the only file that includes Beast and
// Asio (heavy headers stay out of everything else). One io thread runs every
// connection, so the per-client queues need no locks; ViewerState's updates
// reach it through net::post.
#include "rekon/viewer/server.hpp"

#include <spdlog/spdlog.h>

#include <atomic>
#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <deque>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <thread>
#include <unordered_map>

#include "rekon/common/error.hpp"
#include "rekon/viewer/protocol.hpp"
#include "rekon/viewer/web_assets.hpp"

namespace rekon::viewer {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using Request = http::request<http::empty_body>;
using Response = http::response<http::string_body>;

std::chrono::milliseconds millis(double seconds) { return std::chrono::milliseconds(static_cast<int64_t>(seconds * 1000)); }

// A file of the local three.js install, read once at start.
struct StaticFile {
  std::string content_type, body;
};

std::optional<std::string> readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The path of a request target without its query ("/a?b" -> "/a").
std::string_view pathOf(beast::string_view target) {
  const std::string_view t(target.data(), target.size());
  return t.substr(0, t.find('?'));
}

}  // namespace

void ServerOptions::validate() const {
  if (port < 0 || port > 65535) throw Error("viewer.port must be 0..65535 (0: any free port)");
  if (max_clients < 1) throw Error("viewer.max_clients must be 1 or more");
  if (max_client_bytes < (1u << 20)) throw Error("viewer.max_client_mb must be 1 or more");
  if (write_timeout_s <= 0 || header_timeout_s <= 0) throw Error("viewer.write_timeout_s and viewer.header_timeout_s must be > 0");
}

namespace {

// Counts an open connection for as long as it lives (HTTP, then WebSocket).
struct ConnectionSlot {
  explicit ConnectionSlot(std::atomic<size_t>& n) : count(n) { ++count; }
  ~ConnectionSlot() { --count; }
  ConnectionSlot(const ConnectionSlot&) = delete;
  ConnectionSlot& operator=(const ConnectionSlot&) = delete;
  std::atomic<size_t>& count;
};

}  // namespace

class WsSession;

struct Server::Impl {
  Impl(ViewerState& s, const ServerOptions& o) : state(s), opt(o) {}

  ViewerState& state;
  ServerOptions opt;
  std::map<std::string, StaticFile, std::less<>> three_files;
  std::atomic<size_t> connections{0}, ws_clients{0};
  std::atomic<uint64_t> dropped{0}, rejected{0}, messages{0}, bytes{0}, coalesced{0};
  net::io_context ioc{1};
  tcp::acceptor acceptor{ioc};
  std::set<std::shared_ptr<WsSession>> sessions;  // io thread only
  std::thread thread;
  int port = 0;

  void accept();
  void broadcast(const Update& u);
  std::string stateWithClients() const;
  Response route(const Request& req);
};

// One WebSocket client: the full state on connect, then every update through
// a coalescing queue (newest message per key, in first-queued order).
class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(Server::Impl& impl, tcp::socket socket, std::shared_ptr<ConnectionSlot> slot)
      : impl_(impl), ws_(std::move(socket)), slot_(std::move(slot)), write_timer_(ws_.get_executor()) {}

  void run(Request req) {
    req_ = std::move(req);  // kept until the handshake completes
    websocket::stream_base::timeout t{};
    t.handshake_timeout = millis(impl_.opt.header_timeout_s);
    t.idle_timeout = std::chrono::seconds(30);  // a peer that answers no ping for this long is gone
    t.keep_alive_pings = true;
    ws_.set_option(t);
    ws_.read_message_max(impl_.opt.max_ws_message_bytes);
    beast::get_lowest_layer(ws_).expires_never();  // the websocket timeouts take over
    ws_.async_accept(req_, [self = shared_from_this()](beast::error_code ec) { self->onAccept(ec); });
  }

  void enqueue(const Update& u) {
    if (closed_) return;
    auto it = pending_.find(u.key);
    if (it != pending_.end()) {
      pending_bytes_ -= it->second.payload->size();
      it->second = u;
      ++impl_.coalesced;
    } else {
      pending_.emplace(u.key, u);
      order_.push_back(u.key);
    }
    pending_bytes_ += u.payload->size();
    if (pending_bytes_ > impl_.opt.max_client_bytes) {
      drop(fmt::format("{} MB queued", pending_bytes_ >> 20));
      return;
    }
    if (!writing_) writeNext();
  }

  void close() {
    closed_ = true;
    beast::error_code ec;
    beast::get_lowest_layer(ws_).socket().close(ec);
    write_timer_.cancel();
  }

 private:
  void onAccept(beast::error_code ec) {
    if (ec) {
      ++impl_.rejected;
      return;
    }
    ++impl_.ws_clients;
    counted_ = true;
    impl_.sessions.insert(shared_from_this());
    for (const Update& u : impl_.state.snapshot()) enqueue(u);
    enqueue({"live", std::make_shared<const std::string>(R"({"type":"live"})"), false});
    read();
  }

  // A page sends its reports (protocol.hpp); reading also keeps pings and
  // closes flowing and enforces the message limit (larger, or malformed: closed).
  void read() {
    ws_.async_read(in_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec) {
        if (ec != websocket::error::closed && ec != net::error::operation_aborted) ++self->impl_.rejected;
        self->end();
        return;
      }
      if (self->ws_.got_text()) {
        const auto data = self->in_.cdata();
        const std::string_view text(static_cast<const char*>(data.data()), data.size());
        if (auto report = parseClientReport(text)) self->report_ = std::move(*report);
      }
      self->in_.consume(self->in_.size());
      self->read();
    });
  }

 public:
  // The page's newest report as a JSON object; "" before its first.
  const std::string& report() const { return report_; }

 private:

  void writeNext() {
    if (closed_ || order_.empty()) return;
    const std::string key = std::move(order_.front());
    order_.pop_front();
    auto it = pending_.find(key);
    current_ = std::move(it->second);
    pending_.erase(it);
    pending_bytes_ -= current_.payload->size();
    writing_ = true;
    ws_.binary(current_.binary);
    write_timer_.expires_after(millis(impl_.opt.write_timeout_s));
    write_timer_.async_wait([weak = weak_from_this()](beast::error_code ec) {
      if (auto self = weak.lock(); self && !ec) self->drop("a write took longer than viewer.write_timeout_s");
    });
    ws_.async_write(net::buffer(*current_.payload), [self = shared_from_this()](beast::error_code ec, size_t n) {
      self->write_timer_.cancel();
      self->writing_ = false;
      if (ec) {
        self->end();
        return;
      }
      ++self->impl_.messages;
      self->impl_.bytes += n;
      self->writeNext();
    });
  }

  void drop(const std::string& why) {
    if (closed_) return;
    ++impl_.dropped;
    spdlog::warn("viewer: dropped a browser that is not keeping up ({})", why);
    end();
  }

  void end() {
    if (counted_) {
      --impl_.ws_clients;
      counted_ = false;
    }
    close();
    pending_.clear();
    order_.clear();
    pending_bytes_ = 0;
    impl_.sessions.erase(shared_from_this());
  }

  Server::Impl& impl_;
  websocket::stream<beast::tcp_stream> ws_;
  Request req_;
  std::shared_ptr<ConnectionSlot> slot_;
  net::steady_timer write_timer_;
  beast::flat_buffer in_;
  std::unordered_map<std::string, Update> pending_;
  std::deque<std::string> order_;
  size_t pending_bytes_ = 0;
  Update current_;
  std::string report_;
  bool writing_ = false, closed_ = false, counted_ = false;
};

namespace {

// One HTTP request per connection (Connection: close): read the header
// within the time and size limits, answer, close; or hand the socket to a
// WsSession for GET /ws with an upgrade.
class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(Server::Impl& impl, tcp::socket socket)
      : impl_(impl), stream_(std::move(socket)), buffer_(impl.opt.max_header_bytes + 1024),
        slot_(std::make_shared<ConnectionSlot>(impl.connections)) {}

  void run() {
    parser_.header_limit(static_cast<uint32_t>(impl_.opt.max_header_bytes));
    parser_.body_limit(0);  // GET only: any body is refused
    stream_.expires_after(millis(impl_.opt.header_timeout_s));
    http::async_read(stream_, buffer_, parser_,
                     [self = shared_from_this()](beast::error_code ec, size_t) { self->onRead(ec); });
  }

 private:
  void onRead(beast::error_code ec) {
    if (ec == http::error::header_limit) return answerError(http::status::request_header_fields_too_large);
    if (ec == http::error::body_limit || ec == http::error::unexpected_body) return answerError(http::status::payload_too_large);
    if (ec) {  // timeout (a trickling header), a peer that left, or bytes that are not HTTP
      ++impl_.rejected;
      if (ec != beast::error::timeout && ec != http::error::end_of_stream) return answerError(http::status::bad_request);
      return close();
    }
    Request req = parser_.release();
    if (websocket::is_upgrade(req) && pathOf(req.target()) == "/ws") {
      stream_.expires_never();
      std::make_shared<WsSession>(impl_, stream_.release_socket(), slot_)->run(std::move(req));
      return;
    }
    send(impl_.route(req));
  }

  void answerError(http::status status) {
    ++impl_.rejected;
    Response res{status, 11};
    res.set(http::field::content_type, "text/plain");
    res.body() = std::string(http::obsolete_reason(status)) + "\n";
    send(std::move(res));
  }

  void send(Response res) {
    res.keep_alive(false);
    res.prepare_payload();
    response_ = std::make_shared<Response>(std::move(res));
    stream_.expires_after(millis(impl_.opt.write_timeout_s));
    http::async_write(stream_, *response_, [self = shared_from_this()](beast::error_code, size_t) { self->close(); });
  }

  void close() {
    beast::error_code ec;
    stream_.socket().shutdown(tcp::socket::shutdown_both, ec);
    stream_.socket().close(ec);
  }

  Server::Impl& impl_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  http::request_parser<http::empty_body> parser_;
  std::shared_ptr<ConnectionSlot> slot_;
  std::shared_ptr<Response> response_;
};

Response answer(const Request& req, http::status status, std::string_view content_type, std::string body) {
  Response res{status, req.version()};
  res.set(http::field::content_type, beast::string_view(content_type.data(), content_type.size()));
  res.set(http::field::cache_control, "no-store");
  res.body() = std::move(body);
  return res;
}

}  // namespace

Response Server::Impl::route(const Request& req) {
  if (req.method() != http::verb::get) {
    ++rejected;
    return answer(req, http::status::method_not_allowed, "text/plain", "only GET\n");
  }
  // Exact paths only: nothing a request names is ever looked up on disk.
  const std::string_view path = pathOf(req.target());
  if (path == "/mesh.ply") {
    Response res = answer(req, http::status::ok, "application/octet-stream", plyBytes(state.mesh()));
    res.set(http::field::content_disposition, "attachment; filename=\"mesh.ply\"");
    return res;
  }
  if (path == "/state.json") return answer(req, http::status::ok, "application/json", stateWithClients());
  if (const WebAsset* a = findWebAsset(path)) return answer(req, http::status::ok, a->content_type, std::string(a->body));
  if (auto it = three_files.find(path); it != three_files.end()) {
    return answer(req, http::status::ok, it->second.content_type, it->second.body);
  }
  ++rejected;
  return answer(req, http::status::not_found, "text/plain", "not found\n");
}

void Server::Impl::accept() {
  acceptor.async_accept([this](beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted) return;
    if (!ec) {
      if (connections.load() >= static_cast<size_t>(opt.max_clients)) {
        ++rejected;  // over the cap: closed before a byte is read
        beast::error_code ignored;
        socket.close(ignored);
      } else {
        std::make_shared<HttpSession>(*this, std::move(socket))->run();
      }
    }
    accept();
  });
}

// /state.json: the ViewerState's object with "clients": every page's newest report.
std::string Server::Impl::stateWithClients() const {
  std::string json = state.stateJson();
  std::string clients;
  for (const auto& s : sessions) {
    if (!s->report().empty()) clients += (clients.empty() ? "" : ",") + s->report();
  }
  json.pop_back();  // its closing brace
  return json + ",\"clients\":[" + clients + "]}";
}

void Server::Impl::broadcast(const Update& u) {
  // Copied: a session that drops itself leaves the set while we iterate.
  const std::vector<std::shared_ptr<WsSession>> now(sessions.begin(), sessions.end());
  for (const auto& s : now) s->enqueue(u);
}

Server::Server(ViewerState& state, const ServerOptions& options) : impl_(std::make_unique<Impl>(state, options)) {
  options.validate();
  Impl& m = *impl_;
  const std::pair<const char*, const char*> three[] = {{"/three.min.js", "/three.min.js"},
                                                      {"/OrbitControls.js", "/examples/js/controls/OrbitControls.js"}};
  for (const auto& [route, file] : three) {
    if (auto body = readFile(options.three_dir + file)) {
      m.three_files[route] = {"text/javascript", std::move(*body)};
    } else {
      spdlog::warn("viewer: {}{} is missing: the page cannot draw (apt-get install libjs-three, or set viewer.three_dir)",
                   options.three_dir, file);
    }
  }
  beast::error_code ec;
  const auto address = net::ip::make_address(options.bind, ec);
  if (ec) throw Error("viewer.bind '" + options.bind + "' is not an IP address (e.g. 127.0.0.1, or 0.0.0.0 for every interface)");
  const tcp::endpoint endpoint(address, static_cast<unsigned short>(options.port));
  m.acceptor.open(endpoint.protocol(), ec);
  if (!ec) m.acceptor.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) m.acceptor.bind(endpoint, ec);
  if (!ec) m.acceptor.listen(net::socket_base::max_listen_connections, ec);
  if (ec) {
    throw Error(fmt::format("viewer: cannot listen on {}:{} ({}); viewer.bind must be an address of this host and "
                            "viewer.port a free port (0: any free port)",
                            options.bind, options.port, ec.message()));
  }
  m.port = m.acceptor.local_endpoint().port();
}

Server::~Server() { stop(); }

void Server::start() {
  Impl& m = *impl_;
  m.state.setListener([&m](const Update& u) { net::post(m.ioc, [&m, u] { m.broadcast(u); }); });
  m.accept();
  m.thread = std::thread([&m] {
    // One connection's handler that throws costs that connection, not the
    // viewer (an exception out of this thread was std::terminate).
    for (;;) {
      try {
        m.ioc.run();
        return;
      } catch (...) {
        spdlog::error("viewer: a connection handler failed, the server goes on: {}", currentExceptionLine());
      }
    }
  });
}

void Server::stop() {
  Impl& m = *impl_;
  m.state.setListener(nullptr);
  if (!m.thread.joinable()) return;
  m.ioc.stop();
  m.thread.join();
  // The io thread is gone: what it owned is closed here.
  beast::error_code ec;
  m.acceptor.close(ec);
  for (const auto& s : m.sessions) s->close();
  m.sessions.clear();
}

int Server::port() const { return impl_->port; }

std::string Server::url() const {
  return fmt::format("http://{}:{}/", impl_->opt.bind, impl_->port);
}

Server::Counts Server::counts() const {
  const Impl& m = *impl_;
  return {m.connections.load(), m.ws_clients.load(), m.dropped.load(), m.rejected.load(),
          m.messages.load(),    m.bytes.load(),      m.coalesced.load()};
}

}  // namespace rekon::viewer
