// rekon_synth_benchmark [SCENE] [FRAMES]: time of each stage of writing a
// synthetic sequence (ray casting, sensor noise, PNG encoding), one thread.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "../src/png_writer.hpp"
#include "rekon/common/error.hpp"
#include "rekon/synth/synth.hpp"

int main(int argc, char** argv) try {
  const std::string scene_name = argc > 1 ? argv[1] : "room";
  const int frames = argc > 2 ? std::atoi(argv[2]) : 30;
  const auto scene = rekon::synth::Scene::make(scene_name);
  {
    const auto full = scene->trajectory(scene->defaultFrames(), 1);
    double path = 0, vmax = 0, wmax = 0;
    for (size_t i = 1; i < full.size(); ++i) {
      const double dt = full[i].timestamp - full[i - 1].timestamp;
      const double d = rekon::translationDistance(full[i - 1].pose, full[i].pose);
      path += d;
      vmax = std::max(vmax, d / dt);
      wmax = std::max(wmax, rekon::rotationAngle(full[i - 1].pose, full[i].pose) / dt * 57.29577951);
    }
    std::printf("%s trajectory: frames=%d path_m=%.2f max_speed_m_per_s=%.3f max_rotation_deg_per_s=%.1f end_to_start_m=%.4f\n",
                scene_name.c_str(), scene->defaultFrames(), path, vmax, wmax,
                rekon::translationDistance(full.front().pose, full.back().pose));
  }
  const auto traj = scene->trajectory(frames, 1);
  const auto k = rekon::synth::defaultIntrinsics();
  using clock = std::chrono::steady_clock;
  double t_none = 0, t_kinect = 0, t_png = 0;
  size_t bytes = 0;
  for (const auto& sp : traj) {
    auto t0 = clock::now();
    const auto exact = scene->render(k, sp.pose, rekon::synth::Noise::None, 1, 1);
    auto t1 = clock::now();
    const auto noisy = scene->render(k, sp.pose, rekon::synth::Noise::Kinect, 1, 1);
    auto t2 = clock::now();
    bytes += rekon::synth::encodePngFast(noisy.color).size() + rekon::synth::encodePngFast(noisy.depth).size();
    auto t3 = clock::now();
    t_none += std::chrono::duration<double>(t1 - t0).count();
    t_kinect += std::chrono::duration<double>(t2 - t1).count();
    t_png += std::chrono::duration<double>(t3 - t2).count();
  }
  auto t0 = clock::now();
  const auto mesh = scene->groundTruthMesh();
  const double t_mesh = std::chrono::duration<double>(clock::now() - t0).count();
  std::printf("%s, %d frames, one thread: render_none_ms=%.1f render_kinect_ms=%.1f png_ms=%.1f png_kb=%.0f mesh_s=%.2f mesh_vertices=%zu\n",
              scene_name.c_str(), frames, 1e3 * t_none / frames, 1e3 * t_kinect / frames, 1e3 * t_png / frames,
              bytes / 1024.0 / frames, t_mesh, mesh.vertices.size());
} catch (...) {
  std::fprintf(stderr, "rekon_synth_benchmark: %s\n", rekon::currentExceptionLine().c_str());
  return 1;
}
