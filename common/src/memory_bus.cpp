// MemoryBus: the bus without sockets, for unit tests of service logic (see
// bus.hpp). A hub per name holds its live endpoints; publishing copies the
// message into every endpoint's inbox; handle() takes one out and calls the
// handlers subscribed to its channel.
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <utility>
#include <vector>

#include "rekon/common/bus.hpp"

namespace rekon {

struct MemoryBus::Endpoint {
  using Handler = std::function<void(const void*, int)>;
  std::mutex mutex;
  std::condition_variable ready;
  std::deque<std::pair<std::string, std::string>> inbox;  // (channel, bytes), in publication order
  std::multimap<std::string, std::shared_ptr<Handler>> handlers;
};

struct MemoryBus::Hub {
  std::mutex mutex;
  std::vector<std::weak_ptr<Endpoint>> endpoints;
};

namespace {

// memory://NAME -> its hub, alive while a bus of that name is.
std::shared_ptr<MemoryBus::Hub> hubNamed(const std::string& url) {
  static std::mutex mutex;
  static std::map<std::string, std::weak_ptr<MemoryBus::Hub>> hubs;
  std::lock_guard<std::mutex> lock(mutex);
  std::shared_ptr<MemoryBus::Hub> hub = hubs[url].lock();
  if (!hub) {
    hub = std::make_shared<MemoryBus::Hub>();
    hubs[url] = hub;
  }
  return hub;
}

}  // namespace

MemoryBus::MemoryBus(const BusOptions& options)
    : Bus(options), hub_(hubNamed(options.url)), endpoint_(std::make_shared<Endpoint>()) {
  std::lock_guard<std::mutex> lock(hub_->mutex);
  hub_->endpoints.push_back(endpoint_);
}

MemoryBus::~MemoryBus() {
  std::lock_guard<std::mutex> lock(hub_->mutex);
  auto& e = hub_->endpoints;
  e.erase(std::remove_if(e.begin(), e.end(), [&](const auto& w) { return w.expired() || w.lock() == endpoint_; }), e.end());
}

void MemoryBus::publishRaw(const std::string& name, const void* data, int size) {
  const std::string ch = channel(name);
  const std::string bytes(static_cast<const char*>(data), static_cast<size_t>(std::max(size, 0)));
  std::vector<std::shared_ptr<Endpoint>> live;
  {
    std::lock_guard<std::mutex> lock(hub_->mutex);
    for (const auto& w : hub_->endpoints)
      if (auto e = w.lock()) live.push_back(std::move(e));
  }
  for (const auto& e : live) {
    {
      std::lock_guard<std::mutex> lock(e->mutex);
      e->inbox.emplace_back(ch, bytes);
    }
    e->ready.notify_one();
  }
}

void MemoryBus::subscribeRaw(const std::string& name, std::function<void(const void*, int)> handler) {
  std::lock_guard<std::mutex> lock(endpoint_->mutex);
  endpoint_->handlers.emplace(channel(name), std::make_shared<Endpoint::Handler>(std::move(handler)));
}

bool MemoryBus::handle(int timeout_ms) {
  std::pair<std::string, std::string> message;
  std::vector<std::shared_ptr<Endpoint::Handler>> handlers;
  {
    std::unique_lock<std::mutex> lock(endpoint_->mutex);
    if (!endpoint_->ready.wait_for(lock, std::chrono::milliseconds(std::max(timeout_ms, 0)),
                                   [&] { return !endpoint_->inbox.empty(); }))
      return false;
    message = std::move(endpoint_->inbox.front());
    endpoint_->inbox.pop_front();
    const auto [first, last] = endpoint_->handlers.equal_range(message.first);
    for (auto it = first; it != last; ++it) handlers.push_back(it->second);
  }
  if (dropReceived(message.first)) return true;
  // Outside the lock: a handler may publish (its own bus receives that too) or subscribe.
  for (const auto& h : handlers) (*h)(message.second.data(), static_cast<int>(message.second.size()));
  return true;
}

}  // namespace rekon
