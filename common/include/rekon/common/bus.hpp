#pragma once
// The message bus every rekon service talks over: an interface (publish,
// subscribe, dispatch) with two implementations, chosen by the URL: LcmBus
// (LCM over UDP multicast, the real thing) and MemoryBus ("memory://NAME":
// every bus of that name in this process hears every message, as on
// multicast, with no socket: service logic is unit-tested in-process).
// Channel names carry a configurable prefix; messages are decoded here, once,
// with a one-line error for a wrong fingerprint, a truncated buffer, an absurd
// array length or an unknown schema version (the message is dropped, the
// service goes on).
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <new>
#include <stdexcept>
#include <string>

namespace rekon {

class Config;

// Bump when any messages/*.lcm changes.
inline constexpr int32_t kSchemaVersion = 2;  // 2: instance pids on done_t and replay_end_t

// Channel names (after the prefix), one place for all of them.
namespace channel {
inline constexpr const char* kFrames = "FRAMES";
inline constexpr const char* kEndOfStream = "END_OF_STREAM";
inline constexpr const char* kFrameAck = "FRAME_ACK";
inline constexpr const char* kTrackedFrames = "TRACKED_FRAMES";
inline constexpr const char* kKeyframes = "KEYFRAMES";
inline constexpr const char* kConstraints = "CONSTRAINTS";
inline constexpr const char* kGraphUpdates = "GRAPH_UPDATES";
inline constexpr const char* kMeshBlocks = "MESH_BLOCKS";
inline constexpr const char* kMeshRequest = "MESH_REQUEST";
inline constexpr const char* kHeartbeat = "HEARTBEAT";
inline constexpr const char* kStats = "STATS";
inline constexpr const char* kShutdown = "SHUTDOWN";
inline constexpr const char* kDone = "DONE";
// Recovery (messages/recovery.lcm): a replay of the tracker's incremental
// messages goes out on the *_RESENT channels so that live consumers (the
// mapper) never see it twice.
inline constexpr const char* kReplayRequest = "REPLAY_REQUEST";
inline constexpr const char* kReplayEnd = "REPLAY_END";
inline constexpr const char* kResumePoint = "RESUME_POINT";
inline constexpr const char* kKeyframesResent = "KEYFRAMES_RESENT";
inline constexpr const char* kConstraintsResent = "CONSTRAINTS_RESENT";
inline constexpr const char* kTrackedFramesResent = "TRACKED_FRAMES_RESENT";
}  // namespace channel

struct BusOptions {
  std::string url = "udpm://239.255.76.67:7667?ttl=0";  // or memory://NAME (in-process)
  std::string prefix = "REKON_";
  double drop_fraction = 0.0;  // test hook: drop this fraction of received messages
  uint64_t drop_seed = 1;
  static BusOptions fromConfig(const Config& config);
};

// Decodes an LCM message of type Msg; returns false with `why` set for
// anything malformed (never throws, never trusts array lengths blindly).
template <class Msg>
bool decodeMessage(const void* data, int size, Msg* out, std::string* why) {
  if (size <= 0) {
    *why = "empty message";
    return false;
  }
  try {
    if (out->decode(data, 0, size) < 0) {
      *why = "does not decode as " + std::string(Msg::getTypeName()) + " (wrong fingerprint, truncated or absurd lengths)";
      return false;
    }
  } catch (const std::bad_alloc&) {
    *why = "declares an array too large to allocate";
    return false;
  } catch (const std::length_error&) {
    *why = "declares a negative or absurd array length";
    return false;
  }
  if (out->schema_version != kSchemaVersion) {
    *why = "schema_version " + std::to_string(out->schema_version) + " but this build speaks " +
           std::to_string(kSchemaVersion) + "; run the same rekon version everywhere";
    return false;
  }
  return true;
}

class Bus {
 public:
  virtual ~Bus();
  Bus(const Bus&) = delete;
  Bus& operator=(const Bus&) = delete;

  std::string channel(const std::string& name) const { return prefix_ + name; }

  template <class Msg>
  void publish(const std::string& name, Msg msg) {
    msg.schema_version = kSchemaVersion;
    std::string buf(static_cast<size_t>(msg.getEncodedSize()), '\0');
    msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
    publishRaw(name, buf.data(), static_cast<int>(buf.size()));
  }
  virtual void publishRaw(const std::string& name, const void* data, int size) = 0;

  // Handlers run on the thread that calls handle()/spin().
  template <class Msg>
  void subscribe(const std::string& name, std::function<void(const Msg&)> handler) {
    subscribeRaw(name, [this, name, handler = std::move(handler)](const void* data, int size) {
      Msg msg;
      std::string why;
      if (decodeMessage(data, size, &msg, &why)) handler(msg);
      else reportMalformed(name, why);
    });
  }
  virtual void subscribeRaw(const std::string& name, std::function<void(const void*, int)> handler) = 0;

  // Dispatches at most one message; false when none came within timeout_ms.
  virtual bool handle(int timeout_ms) = 0;
  // Dispatches messages until `stop` becomes true.
  void spin(const std::atomic<bool>& stop);

  uint64_t malformedCount() const { return malformed_; }
  uint64_t droppedCount() const { return dropped_; }

 protected:
  explicit Bus(const BusOptions& options);
  // The lcm.drop_fraction test hook: true when this received message is to be
  // dropped (and counted). Which are dropped depends on the channel and the
  // message's place among that channel's messages, not on what else arrived
  // in between (heartbeats, stats), so a run loses the same messages each time.
  bool dropReceived(const std::string& channel);

 private:
  void reportMalformed(const std::string& name, const std::string& why);
  struct DropHook;
  std::string prefix_;
  std::unique_ptr<DropHook> drop_;  // null unless lcm.drop_fraction > 0
  std::atomic<uint64_t> malformed_{0};
  std::atomic<uint64_t> dropped_{0};
};

// LCM over UDP multicast (udpm://...): services on this host or others.
class LcmBus final : public Bus {
 public:
  // Throws rekon::Error when LCM cannot start (e.g. no multicast route).
  explicit LcmBus(const BusOptions& options);
  ~LcmBus() override;
  void publishRaw(const std::string& name, const void* data, int size) override;
  void subscribeRaw(const std::string& name, std::function<void(const void*, int)> handler) override;
  bool handle(int timeout_ms) override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// In-process (memory://NAME): every MemoryBus of the same NAME alive in this
// process receives every message any of them publishes (itself included, as
// LCM multicast does), in publication order, when it calls handle(). Safe to
// publish from any thread; each bus's handlers run on its handle() thread.
class MemoryBus final : public Bus {
 public:
  explicit MemoryBus(const BusOptions& options);
  ~MemoryBus() override;
  void publishRaw(const std::string& name, const void* data, int size) override;
  void subscribeRaw(const std::string& name, std::function<void(const void*, int)> handler) override;
  bool handle(int timeout_ms) override;

  struct Hub;
  struct Endpoint;

 private:
  std::shared_ptr<Hub> hub_;
  std::shared_ptr<Endpoint> endpoint_;
};

// The bus options.url asks for: MemoryBus for memory://NAME, LcmBus otherwise.
std::unique_ptr<Bus> makeBus(const BusOptions& options);

}  // namespace rekon
