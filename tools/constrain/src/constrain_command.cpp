#include "rekon/constrain/constrain.hpp"

#include <fmt/format.h>

#include <spdlog/spdlog.h>

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

// Sent this many times this far apart: UDP may drop one, and the optimiser
// counts repeats of one (source, sequence) once.
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

void waitForOptimiser(ServiceContext& ctx, double seconds) {
  PeerWatch peers(ctx.bus(), ctx.lifecycle());
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (!peers.alive("optimiser")) {
    if (ctx.stopRequested()) return;
    if (std::chrono::steady_clock::now() > until)
      throw Error("no rekon-optimiser heartbeat within " + fmt::format("{}", seconds) +
                  " s: start the run first, or pass --wait 0 to send anyway");
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
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
            .option("wait", "seconds to wait for the optimiser's heartbeat (0: send at once)", "10");
      },
      [](ServiceContext& ctx) {
        const rekon_msgs::external_constraint_t m = messageFromArgs(ctx.args());
        ctx.setState("running");
        const double wait = ctx.args().getDouble("wait");
        if (wait > 0) waitForOptimiser(ctx, wait);
        for (int i = 0; i < kRepeats && !ctx.stopRequested(); ++i) {
          if (i > 0) std::this_thread::sleep_for(kRepeatGap);
          ctx.bus().publish(optimiser::kExternalConstraintsChannel, m);
        }
        spdlog::info("sent {} constraint {} from {}",
                     m.kind == rekon_msgs::external_constraint_t::KIND_PRIOR ? "prior" : "loop", m.sequence, m.source);
      });
}

}  // namespace rekon::constrain
