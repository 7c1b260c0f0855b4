#include "rekon/constrain/constrain.hpp"

#include <fmt/format.h>

#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <sstream>
#include <thread>
#include <vector>

#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/service.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "rekon_msgs/external_constraint_t.hpp"

namespace rekon::constrain {
namespace {

using Clock = std::chrono::steady_clock;

// Sent again this often until the optimiser sends it back: UDP may drop a
// copy, and an optimiser seen starting may not listen yet (a prior sent three
// times within 100 ms of its first heartbeat was lost that way). The
// optimiser counts repeats of one (source, sequence) once.
constexpr auto kResendGap = std::chrono::milliseconds(200);
// With --wait 0 (nobody to acknowledge: a recorded bus, say) it goes out this many times this far apart.
constexpr int kRepeats = 3;
constexpr auto kRepeatGap = std::chrono::milliseconds(50);

// `count` numbers from `text` (spaces or commas between them), or a line naming `what`.
std::vector<double> numbers(std::string text, size_t count, const std::string& what) {
  for (char& c : text) c = c == ',' ? ' ' : c;
  std::istringstream in(text);
  std::vector<double> out;
  double v = 0;
  while (in >> v) out.push_back(v);
  if (!in.eof() || out.size() != count)
    throw Error(what + " needs " + std::to_string(count) + " numbers, got \"" + text + "\"");
  return out;
}

int64_t keyframeId(const std::string& text, const std::string& what) {
  try {
    size_t used = 0;
    const long long id = std::stoll(text, &used);
    if (used == text.size()) return id;
  } catch (const std::exception&) {
  }
  throw Error(what + " must be a keyframe id (an integer), got \"" + text + "\"");
}

// The message the options describe.
rekon_msgs::external_constraint_t messageFromArgs(const ArgParser& args) {
  rekon_msgs::external_constraint_t m{};
  if (args.has("prior") == args.has("loop")) throw Error("give one of --prior KEYFRAME or --loop FROM,TO (see --help)");
  if (args.has("prior")) {
    m.kind = rekon_msgs::external_constraint_t::KIND_PRIOR;
    m.from_id = -1;
    m.to_id = keyframeId(args.get("prior"), "--prior");
  } else {
    m.kind = rekon_msgs::external_constraint_t::KIND_LOOP;
    const std::string loop = args.get("loop");
    const size_t comma = loop.find(',');
    if (comma == std::string::npos) throw Error("--loop needs FROM,TO (two keyframe ids), got \"" + loop + "\"");
    m.from_id = keyframeId(loop.substr(0, comma), "--loop FROM");
    m.to_id = keyframeId(loop.substr(comma + 1), "--loop TO");
  }
  if (!args.has("pose")) throw Error("--pose \"tx ty tz qx qy qz qw\" is required");
  const std::vector<double> pose = numbers(args.get("pose"), 7, "--pose");
  std::copy_n(pose.begin(), 3, m.pose.t);
  std::copy_n(pose.begin() + 3, 4, m.pose.q);
  if (args.has("information")) {
    const std::vector<double> info = numbers(args.get("information"), 36, "--information");
    std::copy(info.begin(), info.end(), m.information);
  } else {
    const std::vector<double> sigma = numbers(args.get("sigma"), 2, "--sigma");
    if (!(sigma[0] > 0) || !(sigma[1] > 0)) throw Error("--sigma T,R must be two positive numbers (metres, radians)");
    for (int i = 0; i < 6; ++i) m.information[i * 7] = 1.0 / (sigma[i < 3 ? 0 : 1] * sigma[i < 3 ? 0 : 1]);
  }
  m.source = args.get("source");
  m.sequence = args.has("sequence") ? keyframeId(args.get("sequence"), "--sequence")
                                    : std::chrono::duration_cast<std::chrono::microseconds>(
                                          std::chrono::system_clock::now().time_since_epoch())
                                          .count();
  optimiser::externalConstraintFromMsg(m);  // the optimiser's own checks, so that bad input fails here
  return m;
}

// Sends one constraint to the optimiser and waits for it to come back. The
// bus thread writes into it: stop that thread before it dies.
class AcknowledgedSend {
 public:
  AcknowledgedSend(ServiceContext& ctx, const rekon_msgs::external_constraint_t& m, double wait_s)
      : ctx_(ctx), m_(m), wait_s_(wait_s), peers_(ctx.bus(), ctx.lifecycle()) {
    ctx.bus().subscribe<rekon_msgs::external_constraint_t>(
        optimiser::kExternalConstraintsAckChannel, [this](const rekon_msgs::external_constraint_t& ack) {
          if (ack.source == m_.source && ack.sequence == m_.sequence) acknowledged_ = true;
        });
  }

  // Waits for the optimiser's heartbeat, then sends until it sends the
  // constraint back; throws at the deadline. Returns the copies sent.
  int run() {
    const auto until = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(wait_s_));
    while (!peers_.alive("optimiser")) {
      if (ctx_.stopRequested()) return 0;
      if (Clock::now() > until)
        throw Error(fmt::format("no rekon-optimiser heartbeat within {} s: start the run first, or pass --wait 0 to "
                                "send anyway", wait_s_));
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    int sent = 0;
    while (!acknowledged_ && !ctx_.stopRequested()) {
      if (Clock::now() > until)
        throw Error(fmt::format("rekon-optimiser did not acknowledge constraint {} within {} s ({} copies sent): is "
                                "it overloaded? Pass a longer --wait",
                                m_.sequence, wait_s_, sent));
      ctx_.bus().publish(optimiser::kExternalConstraintsChannel, m_);
      ++sent;
      for (auto next = Clock::now() + kResendGap; !acknowledged_ && Clock::now() < next;)
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return sent;
  }

 private:
  ServiceContext& ctx_;
  const rekon_msgs::external_constraint_t m_;
  const double wait_s_;
  PeerWatch peers_;
  std::atomic<bool> acknowledged_{false};
};

void sendWithoutWaiting(ServiceContext& ctx, const rekon_msgs::external_constraint_t& m) {
  for (int i = 0; i < kRepeats && !ctx.stopRequested(); ++i) {
    if (i > 0) std::this_thread::sleep_for(kRepeatGap);
    ctx.bus().publish(optimiser::kExternalConstraintsChannel, m);
  }
}

}  // namespace

int constrainCommand(int argc, char** argv) {
  return runService(
      argc, argv, "constrain",
      "Sends an external constraint to the running optimiser: a loop edge between two keyframes (--loop FROM,TO, "
      "--pose = TO in FROM) or an absolute pose prior on one (--prior KF, --pose = its world pose), with its "
      "information (--sigma T,R for a diagonal one, or --information with 36 numbers, row-major, tx ty tz rx ry rz).",
      [](ArgParser& args) {
        args.option("prior", "keyframe id: an absolute pose prior on it")
            .option("loop", "FROM,TO: a loop edge between two keyframes")
            .option("pose", "\"tx ty tz qx qy qz qw\": the prior's world pose, or TO's pose in FROM")
            .option("sigma", "T,R: standard deviations in metres and radians (diagonal information)", "0.01,0.01")
            .option("information", "36 numbers: the full 6x6 information matrix instead of --sigma")
            .option("source", "who sends it (named in the optimiser's log)", "rekon constrain")
            .option("sequence", "this constraint's number for its source (default: the time in microseconds)")
            .option("wait", "seconds to wait for the optimiser's heartbeat and acknowledgement (0: send 3 copies at once, "
                    "unacknowledged)", "10");
      },
      [](ServiceContext& ctx) {
        const rekon_msgs::external_constraint_t m = messageFromArgs(ctx.args());
        ctx.setState("running");
        const double wait = ctx.args().getDouble("wait");
        const char* kind = m.kind == rekon_msgs::external_constraint_t::KIND_PRIOR ? "prior" : "loop";
        if (!(wait > 0)) {
          sendWithoutWaiting(ctx, m);
          spdlog::info("sent {} constraint {} from {} {} times (not waiting for an acknowledgement)", kind, m.sequence,
                       m.source, kRepeats);
          return;
        }
        AcknowledgedSend send(ctx, m, wait);
        StopThreadsOnExit stop_threads(ctx);  // before `send` dies: the bus thread writes into it
        const int sent = send.run();
        if (!ctx.stopRequested())
          spdlog::info("sent {} constraint {} from {}: rekon-optimiser acknowledged it after {} cop{}", kind,
                       m.sequence, m.source, sent, sent == 1 ? "y" : "ies");
      });
}

}  // namespace rekon::constrain
