// Streaming on a synthetic scene (default: the 36 m corridor of tools/synth):
// integrates the ground-truth sequence with the streaming sphere around the
// camera and prints active vs total blocks over time, plus the streaming cost.
//   rekon_volume_streaming_benchmark [--scene corridor] [--radius 4] [--every 100]
#include <sys/resource.h>

#include <chrono>
#include <cstdio>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/logging.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"
#include "rekon/synth/synth.hpp"

int main(int argc, char** argv) try {
  rekon::setupLogging("volume_streaming", "warn");
  rekon::ArgParser args("rekon_volume_streaming_benchmark", "active vs total blocks with streaming on a synthetic scene");
  args.option("scene", "room, corridor or tabletop", "corridor")
      .option("radius", "streaming radius in metres", "4.0")
      .option("frames", "frames (0 = the scene's default)", "0")
      .option("level", "image pyramid level rendered (0 = 640x480, 1 = 320x240)", "1")
      .option("every", "print a line every this many frames", "100");
  if (!args.parse(argc, argv)) return 0;
  const auto scene = rekon::synth::Scene::make(args.get("scene"));
  const int frames = args.getInt("frames") > 0 ? args.getInt("frames") : scene->defaultFrames();
  const rekon::Intrinsics k = rekon::synth::defaultIntrinsics().atLevel(args.getInt("level"));
  const rekon::Trajectory trajectory = scene->trajectory(frames, 1);

  rekon::volume::VolumeParams params;
  params.streaming_radius = args.getDouble("radius");
  rekon::volume::TsdfVolume volume(params);
  double stream_ms = 0.0, integrate_ms = 0.0;
  const int every = std::max(1, args.getInt("every"));
  std::printf("frame total_blocks active_blocks host_blocks streamed_out streamed_in\n");
  for (int i = 0; i < frames; ++i) {
    const rekon::RgbdFrame f = scene->render(k, trajectory[i].pose, rekon::synth::Noise::None, 1);
    const cv::Mat depth = rekon::volume::depthToMetres(f.depth, k.depth_scale);
    auto t = std::chrono::steady_clock::now();
    volume.streamAround(trajectory[i].pose.translation());
    stream_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
    t = std::chrono::steady_clock::now();
    volume.integrate(depth, f.color, cv::Mat(), k, trajectory[i].pose);
    integrate_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
    if (i % every == 0 || i == frames - 1) {
      const auto s = volume.stats();
      std::printf("%d %lld %lld %lld %lld %lld\n", i, static_cast<long long>(s.blocks),
                  static_cast<long long>(s.active_blocks), static_cast<long long>(s.host_blocks),
                  static_cast<long long>(s.streamed_out), static_cast<long long>(s.streamed_in));
    }
  }
  const auto s = volume.stats();
  std::printf("scene=%s frames=%d radius=%.1f image=%dx%d stream_ms_per_frame=%.2f integrate_ms_per_frame=%.2f "
              "blocks=%lld peak_active=%lld\n",
              args.get("scene").c_str(), frames, params.streaming_radius, k.width, k.height, stream_ms / frames,
              integrate_ms / frames, static_cast<long long>(s.blocks), static_cast<long long>(s.peak_active_blocks));
  return 0;
} catch (...) {
  std::fprintf(stderr, "rekon_volume_streaming_benchmark: %s\n", rekon::currentExceptionLine().c_str());
  return 1;
}
