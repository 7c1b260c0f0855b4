#include "rekon/common/bus.hpp"

#include <lcm/lcm.h>
#include <spdlog/spdlog.h>

#include <exception>
#include <mutex>
#include <functional>
#include <map>
#include <utility>
#include <vector>

#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"

namespace rekon {

BusOptions BusOptions::fromConfig(const Config& config) {
  BusOptions o;
  o.url = config.getString("lcm.url");
  o.prefix = config.getString("lcm.channel_prefix");
  o.drop_fraction = config.getDouble("lcm.drop_fraction");
  if (o.drop_fraction < 0 || o.drop_fraction >= 1) throw Error("lcm.drop_fraction must be in [0, 1)");
  return o;
}

struct Bus::DropHook {
  std::mutex mutex;  // MemoryBus handlers may run while another thread publishes
  double fraction;
  uint64_t seed;
  std::map<std::string, uint64_t> received;  // per channel
};

namespace {

// SplitMix64's finaliser: a well-mixed 64-bit value of `x`.
uint64_t mix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

}  // namespace

Bus::Bus(const BusOptions& options) : prefix_(options.prefix) {
  if (options.drop_fraction > 0) {
    drop_ = std::make_unique<DropHook>();
    drop_->fraction = options.drop_fraction;
    drop_->seed = options.drop_seed;
  }
}

Bus::~Bus() = default;

bool Bus::dropReceived(const std::string& channel) {
  if (!drop_) return false;
  std::lock_guard<std::mutex> lock(drop_->mutex);
  const uint64_t n = drop_->received[channel]++;
  const uint64_t h = mix(mix(std::hash<std::string>{}(channel) ^ drop_->seed) ^ n);
  if (static_cast<double>(h >> 11) * 0x1.0p-53 >= drop_->fraction) return false;
  ++dropped_;
  return true;
}

void Bus::spin(const std::atomic<bool>& stop) {
  while (!stop.load()) handle(100);
}

void Bus::reportMalformed(const std::string& name, const std::string& why) {
  const uint64_t n = ++malformed_;
  // The first few are logged each; a flood is summarised instead of drowning the log.
  if (n <= 10 || n % 1000 == 0) {
    spdlog::error("dropped a malformed message on {}: {} ({} malformed so far)", channel(name), why, n);
  }
}

std::unique_ptr<Bus> makeBus(const BusOptions& options) {
  if (options.url.rfind("memory://", 0) == 0) return std::make_unique<MemoryBus>(options);
  return std::make_unique<LcmBus>(options);
}

// ---- LcmBus

struct LcmBus::Impl {
  struct Subscription {
    LcmBus* bus;
    std::function<void(const void*, int)> handler;
  };
  lcm_t* lcm = nullptr;
  std::vector<std::unique_ptr<Subscription>> subscriptions;
  // A handler's exception, held while liblcm's C frames are on the stack (C++
  // unwinding through them is undefined) and thrown again by handle().
  std::exception_ptr handler_error;
};

namespace {

// Inline frames are 0.5-1 MB; the kernel's default UDP receive buffer (about
// 200 KB) holds less than one, so a receiver busy for a moment loses frames.
// Ask for 4 MiB unless the URL says otherwise (the kernel caps it at
// net.core.rmem_max).
constexpr const char* kRecvBufOption = "recv_buf_size=4194304";

// Messages of one channel waiting for dispatch at most (liblcm's default: 30).
constexpr int kQueueCapacity = 1024;

std::string withReceiveBuffer(const std::string& url) {
  if (url.rfind("udpm://", 0) != 0 || url.find("recv_buf_size") != std::string::npos) return url;
  return url + (url.find('?') == std::string::npos ? "?" : "&") + kRecvBufOption;
}

}  // namespace

LcmBus::LcmBus(const BusOptions& options) : Bus(options), impl_(std::make_unique<Impl>()) {
  impl_->lcm = lcm_create(withReceiveBuffer(options.url).c_str());
  if (!impl_->lcm) {
    throw Error("LCM could not start on " + options.url +
                "; check that a multicast route exists (ip route add 224.0.0.0/4 dev lo) and lcm.url is valid");
  }
}

LcmBus::~LcmBus() {
  if (impl_->lcm) lcm_destroy(impl_->lcm);
}

void LcmBus::publishRaw(const std::string& name, const void* data, int size) {
  if (lcm_publish(impl_->lcm, channel(name).c_str(), data, static_cast<unsigned>(size)) != 0) {
    spdlog::warn("LCM publish on {} failed ({} bytes); the message is lost", channel(name), size);
  }
}

void LcmBus::subscribeRaw(const std::string& name, std::function<void(const void*, int)> handler) {
  auto sub = std::make_unique<Impl::Subscription>(Impl::Subscription{this, std::move(handler)});
  auto trampoline = [](const lcm_recv_buf_t* rbuf, const char* channel, void* user) {
    auto* s = static_cast<Impl::Subscription*>(user);
    try {
      if (s->bus->dropReceived(channel)) return;
      s->handler(rbuf->data, static_cast<int>(rbuf->data_size));
    } catch (...) {
      s->bus->impl_->handler_error = std::current_exception();
    }
  };
  // LCM channel names are regular expressions; ours are plain words.
  std::string pattern = channel(name);
  pattern.insert(0, 1, '^').push_back('$');
  lcm_subscription_t* subscription = lcm_subscribe(impl_->lcm, pattern.c_str(), trampoline, sub.get());
  // liblcm drops a message when 30 of its channel wait to be dispatched (its
  // default): a replay batch or a burst of tracked frames while this process
  // was not scheduled lost most of a batch that way.
  if (subscription) lcm_subscription_set_queue_capacity(subscription, kQueueCapacity);
  impl_->subscriptions.push_back(std::move(sub));
}

bool LcmBus::handle(int timeout_ms) {
  const int r = lcm_handle_timeout(impl_->lcm, timeout_ms);
  if (impl_->handler_error) std::rethrow_exception(std::exchange(impl_->handler_error, nullptr));
  if (r < 0) throw Error("LCM receive failed; the bus is down (check the network namespace and multicast route)");
  return r > 0;
}

}  // namespace rekon
