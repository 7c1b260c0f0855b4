#include "rekon/frontend_check/frontend_check.hpp"

#include <lcm/lcm-cpp.hpp>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <mutex>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/common/service.hpp"
#include "rekon/frontend_check/checker.hpp"

namespace rekon::frontend_check {
namespace {

// After the frontend's done_t, late messages (the repeats of done_t, a final
// graph update sent again) still count for this long.
constexpr double kLingerAfterDoneS = 1.0;

// The channels the contract covers, without the prefix.
const std::vector<const char*>& contractChannels() {
  static const std::vector<const char*> names = {channel::kFrames,        channel::kFrameAck,    channel::kKeyframes,
                                                 channel::kTrackedFrames, channel::kConstraints, channel::kGraphUpdates,
                                                 channel::kDone};
  return names;
}

int64_t nowUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

CheckOptions optionsFromArgs(const ArgParser& args) {
  CheckOptions o;
  o.ack_service = args.get("ack-name");
  o.done_service = args.get("done-service");
  o.max_latency_ms = args.getDouble("max-latency-ms");
  if (o.ack_service.empty() || o.done_service.empty())
    throw Error("--ack-name and --done-service must name a service (e.g. tracker, optimiser)");
  if (!(o.max_latency_ms > 0)) throw Error("--max-latency-ms must be a positive number of milliseconds");
  return o;
}

// An lcm-logger log: every event on a contract channel, at its logged time.
void feedLog(const std::string& path, const std::string& prefix, Checker& checker) {
  lcm::LogFile log(path, "r");
  if (!log.good()) throw Error(path + ": cannot open as an lcm-logger log; check the path");
  while (const lcm::LogEvent* e = log.readNextEvent()) {
    if (e->channel.compare(0, prefix.size(), prefix) != 0) continue;
    checker.feed(e->channel.substr(prefix.size()), e->timestamp, e->data, e->datalen);
  }
  if (checker.messages() == 0)
    throw Error(path + ": no message on a frontend channel (" + prefix +
                "KEYFRAMES, ...): not an lcm-logger log of a rekon run, or another lcm.channel_prefix");
}

// The bus until the frontend's done_t (and a linger), a stop, or the timeout.
void feedLive(ServiceContext& ctx, double timeout_s, Checker& checker) {
  std::mutex mutex;
  StopThreadsOnExit stop_threads(ctx);  // after `mutex`: the handlers use it (and `checker`, the caller's)
  for (const char* name : contractChannels()) {
    ctx.bus().subscribeRaw(name, [&, channel = std::string(name)](const void* data, int size) {
      const int64_t t = nowUs();
      std::lock_guard<std::mutex> lock(mutex);
      checker.feed(channel, t, data, size);
    });
  }
  ctx.setState("running");
  // The line a script waits for before it starts the frontend.
  std::printf("listening for a frontend on the bus (up to %.0f s)\n", timeout_s);
  std::fflush(stdout);
  const auto start = std::chrono::steady_clock::now();
  std::optional<std::chrono::steady_clock::time_point> done_at;
  while (!ctx.stopRequested()) {
    const auto now = std::chrono::steady_clock::now();
    if (std::chrono::duration<double>(now - start).count() > timeout_s) {
      spdlog::warn("--timeout of {:.0f} s reached before the frontend's done_t; judging what arrived", timeout_s);
      break;
    }
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (!done_at && checker.frontendDone()) done_at = now;
    }
    if (done_at && std::chrono::duration<double>(now - *done_at).count() > kLingerAfterDoneS) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

}  // namespace

int frontendCheckCommand(int argc, char** argv) {
  return runService(
      argc, argv, "frontend-check",
      "Judges a frontend (whatever publishes keyframes, tracked frames, constraints, graph updates and done_t) "
      "against every rule of messages/FRONTEND.md, from the bus or an lcm-logger log; one line per rule, exit 1 on "
      "a failure.",
      [](ArgParser& args) {
        args.option("log", "an lcm-logger log to judge instead of listening on the bus")
            .option("ack-name", "the name the frame source waits for (player.wait_for)", "tracker")
            .option("done-service", "the service whose done_t ends the frontend's work", "optimiser")
            .option("max-latency-ms", "a frame answered later than this fails FC11",
                    std::to_string(CheckOptions::kDefaultMaxLatencyMs))
            .option("timeout", "seconds to listen before judging when no done_t comes", "300");
      },
      [](ServiceContext& ctx) {
        Checker checker(optionsFromArgs(ctx.args()));
        if (ctx.args().has("log")) feedLog(ctx.args().get("log"), ctx.config().getString("lcm.channel_prefix"), checker);
        else feedLive(ctx, ctx.args().getDouble("timeout"), checker);
        const std::vector<RuleResult> results = checker.judge();
        int failed = 0;
        for (const RuleResult& r : results) {
          std::printf("%s\n", formatResult(r).c_str());
          failed += r.passed ? 0 : 1;
        }
        std::fflush(stdout);
        ctx.stats().set("messages", static_cast<long long>(checker.messages())).set("rules_failed", failed);
        if (failed > 0)
          throw Error(std::to_string(failed) + " of " + std::to_string(results.size()) +
                      " rules of messages/FRONTEND.md failed; the FAIL lines name the first offending message");
      });
}

}  // namespace rekon::frontend_check
