// rekon-synth-source: a frame source that renders an analytic scene
// (tools/synth) frame by frame as it plays, instead of reading a dataset
// written to disk first (the 60-minute building would be about 75 GB of
// PNGs). To the other services it is the player: it runs as "player",
// waits for player.wait_for, and sends through the same FrameSender and,
// live, the same LiveOutlet as rekon-player (skipped and dropped frames,
// <out>/player_latency.csv). It also writes <out>/source_counts.csv once a
// second, so a stopped run keeps what the source did.
#include <spdlog/spdlog.h>

#include <chrono>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/common/frame_source.hpp"
#include "rekon/common/service.hpp"
#include "rekon/synth/synth.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

struct SourceParams {
  std::string scene;
  int frames = 0, laps = 1, render_threads = 1;
  uint64_t seed = 1;
  rekon::synth::Noise noise = rekon::synth::Noise::Kinect;
  double rate = 1.0;  // a multiple of 30 Hz; 0 = unpaced (as fast as the consumers acknowledge)
};

void runSource(rekon::ServiceContext& ctx, const SourceParams& p) {
  const auto scene = rekon::synth::Scene::make(p.scene);
  const int frames = p.frames > 0 ? p.frames : scene->defaultFrames(p.laps);
  const rekon::Trajectory trajectory = scene->trajectory(frames, p.seed, p.laps);
  const rekon::Intrinsics k = rekon::synth::defaultIntrinsics();
  const rekon::Config& config = ctx.config();
  const std::vector<std::string> consumers = config.getStringList("player.wait_for");
  rekon::ConsumerWatch watch(ctx.bus());
  rekon::PeerWatch peers(ctx.bus(), ctx.lifecycle());
  rekon::StopThreadsOnExit stop_threads(ctx);
  rekon::waitForConsumers(ctx, watch, consumers, config.getDouble("player.wait_timeout_s"), "player.wait_for");
  const rekon::TransportMode mode = rekon::chooseTransport(config.getString("transport.mode"), consumers, watch);
  rekon::FrameSender sender(ctx.bus(), mode, config.getString("transport.segment"),
                            rekon::FrameRingLayout{static_cast<int>(config.getInt("transport.slots")),
                                                   static_cast<int>(config.getInt("transport.max_width")),
                                                   static_cast<int>(config.getInt("transport.max_height"))});
  spdlog::info("scene {}: {} frames ({:.1f} min), rendered as they play, {}", p.scene, frames, frames / 1800.0,
               p.rate > 0 ? fmt::format("live at {:.0f} Hz", 30.0 * p.rate) : std::string("unpaced"));
  rekon::SourceCountsLog counts(ctx.outDir());
  auto render = [&](int64_t id) {
    rekon::RgbdFrame f = scene->render(k, trajectory[static_cast<size_t>(id)].pose, p.noise,
                                       rekon::synth::frameSeed(p.seed, id), p.render_threads);
    f.id = id;
    f.timestamp = trajectory[static_cast<size_t>(id)].timestamp;
    return f;
  };
  ctx.setState("playing");
  const Clock::time_point start = Clock::now();
  double render_ms = 0;
  int64_t rendered = 0, sent = 0, last = -1;
  auto timed = [&](int64_t id) {
    const Clock::time_point t0 = Clock::now();
    rekon::RgbdFrame f = render(id);
    const double ms = 1e3 * since(t0);
    render_ms += ms;
    counts.frameMade(ms);
    ++rendered;
    return f;
  };
  if (p.rate > 0) {
    rekon::LiveOutlet outlet(ctx, sender, watch, consumers, static_cast<int>(config.getInt("transport.live_in_flight")));
    const double period = 1.0 / (30.0 * p.rate);
    for (int64_t id = 0; id < frames && !ctx.stopRequested(); ++id) {
      std::this_thread::sleep_until(start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(id * period)));
      // A camera does not wait for a busy computer: frames whose time has passed are never rendered.
      const int64_t due = std::min<int64_t>(frames - 1, std::max<int64_t>(id, static_cast<int64_t>(since(start) / period)));
      outlet.skippedLate(due - id);
      id = due;
      rekon::RgbdFrame f = timed(id);
      outlet.offer(std::move(f), k, std::max(0.0, since(start) - id * period));
      last = id;
      ++sent;
      ctx.setLastFrame(id);
      counts.row(id + 1, outlet.counts());
    }
    outlet.finish(config.getDouble("player.wait_timeout_s"));
    outlet.writeStats(ctx.stats());
    const auto c = outlet.counts();
    counts.row(last + 1, c, true);
    spdlog::info("live: {} frames sent, {} dropped, {} skipped (their time had passed while rendering)", c.sent, c.dropped,
                 c.skipped_late);
  } else {
    const int in_flight = mode == rekon::TransportMode::kShm ? sender.slots() - 1 : 2;
    for (int64_t id = 0; id < frames && !ctx.stopRequested(); ++id) {
      if (id >= in_flight) {
        while (!ctx.stopRequested() &&
               watch.waitForAck(consumers, id - in_flight, 1.0, ctx) == rekon::ConsumerWatch::Wait::kStalled) {
          if (watch.silentSeconds() > config.getDouble("player.wait_timeout_s"))
            throw rekon::Error("the consumers acknowledged no frame for player.wait_timeout_s; see their logs");
        }
      }
      sender.send(timed(id), k);
      last = id;
      ++sent;
      ctx.setLastFrame(id);
      counts.row(id + 1, {.sent = sent});
    }
    if (last >= 0) watch.waitForAck(consumers, last, config.getDouble("player.wait_timeout_s"), ctx);
    counts.row(last + 1, {.sent = sent}, true);
  }
  const double wall = since(start);
  rekon_msgs::end_of_stream_t eos{};
  eos.last_frame_id = last;
  eos.frames = sent;
  eos.duration_s = last >= 0 ? (last + 1) / 30.0 : 0.0;
  rekon::announceEndOfStream(ctx.bus(), eos);
  ctx.stats()
      .set("frames", static_cast<long long>(sent))
      .set("sequence_seconds", eos.duration_s)
      .set("wall_seconds", wall)
      .set("render_ms_mean", rendered > 0 ? render_ms / static_cast<double>(rendered) : 0.0)
      .set("render_threads", static_cast<long long>(p.render_threads));
  spdlog::info("rendered {} frames, {:.1f} ms each on {} thread(s)", rendered, rendered > 0 ? render_ms / rendered : 0.0,
               p.render_threads);
  // The ring lives as long as the sender: stay until the consumers are done with it.
  ctx.setState("lingering");
  while (!ctx.stopRequested() && !peers.finished(consumers)) std::this_thread::sleep_for(std::chrono::milliseconds(50));
}

}  // namespace

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "player", "Renders a synthetic scene frame by frame and publishes it as rekon-player does.",
      [](rekon::ArgParser& args) {
        args.option("scene", "room, corridor, tabletop or building", "building")
            .option("frames", "frames to play (0 = the scene's default for --laps)", "0")
            .option("laps", "laps of the scene's walk", "1")
            .option("seed", "seed of the walk's shake and of the sensor noise", "1")
            .option("noise", "kinect or none", "kinect")
            .option("rate", "a multiple of 30 Hz played live (frames the consumers are not ready for are dropped), "
                            "or max: unpaced, each frame sent once the consumers acknowledged the one before", "1")
            .option("render-threads", "threads that ray cast each frame", "1");
      },
      [](rekon::ServiceContext& ctx) {
        const rekon::ArgParser& a = ctx.args();
        SourceParams p;
        p.scene = a.get("scene");
        p.frames = a.getInt("frames");
        p.laps = a.getInt("laps");
        p.seed = static_cast<uint64_t>(a.getInt("seed"));
        p.noise = rekon::synth::parseNoise(a.get("noise"));
        p.render_threads = a.getInt("render-threads");
        if (p.frames < 0 || p.render_threads < 1 || p.render_threads > 64)
          throw rekon::Error("--frames must be 0 or more and --render-threads 1 to 64");
        const std::string rate = a.get("rate");
        if (rate == "max") {
          p.rate = 0;
        } else {
          try {
            p.rate = std::stod(rate);
          } catch (const std::exception&) {
            p.rate = -1;
          }
          if (!(p.rate > 0)) throw rekon::Error("--rate '" + rate + "' must be max or a positive multiple of 30 Hz");
        }
        runSource(ctx, p);
      });
}
