// writeSequence and drift: a whole TUM-layout sequence on disk.
#include <atomic>

#include <fmt/format.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <numbers>
#include <thread>

#include "analytic_scene.hpp"
#include "rekon/progress/progress_line.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/image_io.hpp"
#include "png_writer.hpp"
#include "sensor_noise.hpp"

namespace fs = std::filesystem;

namespace rekon::synth {
namespace {

std::string stamp(double t) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.6f", t);
  return buf;
}

void writeBytes(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw Error(path + ": cannot write; check that the output folder is writable and the disk not full");
}

Eigen::Matrix3d expSo3(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

}  // namespace

Trajectory driftedTrajectory(const Trajectory& ground_truth, double translation_per_m, double rotation_deg_per_m,
                             uint64_t seed) {
  if (!(translation_per_m >= 0) || !(rotation_deg_per_m >= 0)) {
    throw Error("drift must be non-negative: got " + fmt::format("{}", translation_per_m) + " m/m, " +
                fmt::format("{}", rotation_deg_per_m) + " deg/m");
  }
  Trajectory out = ground_truth;
  Rng rng(mixSeed(seed, 0xD21F7ull));
  const double per_axis = 1.0 / std::sqrt(3.0);
  for (size_t i = 1; i < out.size(); ++i) {
    const Pose rel = ground_truth[i - 1].pose.inverse() * ground_truth[i].pose;
    const double root_ds = std::sqrt(rel.translation().norm());
    const double sigma_t = translation_per_m * per_axis * root_ds;
    const double sigma_r = rotation_deg_per_m * std::numbers::pi / 180.0 * per_axis * root_ds;
    Pose eps = Pose::Identity();
    Eigen::Vector3d dt, dr;
    for (int k = 0; k < 3; ++k) dt[k] = sigma_t * rng.normal();
    for (int k = 0; k < 3; ++k) dr[k] = sigma_r * rng.normal();
    eps.linear() = expSo3(dr);
    eps.translation() = dt;
    out[i].pose = orthonormalised(out[i - 1].pose * rel * eps);
  }
  return out;
}

size_t writeGroundTruth(const Scene& scene, const Trajectory& trajectory, const Intrinsics& k, const std::string& out_dir) {
  writeTumTrajectory(trajectory, (fs::path(out_dir) / "groundtruth.txt").string());
  saveIntrinsics(k, (fs::path(out_dir) / "camera.yaml").string());
  const Mesh mesh = scene.groundTruthMesh();
  writePly(mesh, (fs::path(out_dir) / "mesh_gt.ply").string());
  return mesh.vertices.size();
}

SequenceReport writeSequence(const SequenceOptions& options, const std::string& out_dir) {
  const auto start = std::chrono::steady_clock::now();
  const auto scene = Scene::make(options.scene);
  const int frames = options.frames > 0 ? options.frames : scene->defaultFrames(options.laps);
  if (options.frames < 0) throw Error("--frames " + std::to_string(options.frames) + " is negative; give 1 or more (0 = scene default)");
  if (options.jpeg_quality < 0 || options.jpeg_quality > 100)
    throw Error("--jpeg " + std::to_string(options.jpeg_quality) + " must lie in [1, 100], or 0 for PNG color");
  const std::string color_ext = options.jpeg_quality > 0 ? ".jpg" : ".png";
  createOutputFolder((fs::path(out_dir) / "rgb").string());
  createOutputFolder((fs::path(out_dir) / "depth").string());
  const Intrinsics k = defaultIntrinsics();
  const Trajectory trajectory = scene->trajectory(frames, options.seed, options.laps);

  // Frames in parallel, each rendered on one thread: rendering and PNG
  // encoding then both use every core.
  const int workers = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  std::atomic<int> next{0}, done{0};
  std::mutex error_mutex;
  std::string first_error;
  auto work = [&] {
    for (;;) {
      const int i = next.fetch_add(1);
      if (i >= frames) return;
      try {
        const auto& sp = trajectory[static_cast<size_t>(i)];
        const RgbdFrame f = scene->render(k, sp.pose, options.noise, frameSeed(options.seed, i), 1);
        const std::string name = stamp(sp.timestamp);
        writeBytes((fs::path(out_dir) / "rgb" / (name + color_ext)).string(),
                   options.jpeg_quality > 0 ? encodeJpeg(f.color, options.jpeg_quality) : encodePngFast(f.color));
        writeBytes((fs::path(out_dir) / "depth" / (name + ".png")).string(), encodePngFast(f.depth));
        if (options.on_frame) options.on_frame(++done, frames);
      } catch (const std::exception& e) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (first_error.empty()) first_error = e.what();
        next = frames;
      }
    }
  };
  std::vector<std::thread> pool;
  for (int i = 1; i < workers; ++i) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
  if (!first_error.empty()) throw Error(first_error);

  std::ofstream rgb_txt(fs::path(out_dir) / "rgb.txt"), depth_txt(fs::path(out_dir) / "depth.txt");
  std::string command = "rekon synth --scene " + options.scene + " --seed " + std::to_string(options.seed);
  if (options.laps != 1) command += " --laps " + std::to_string(options.laps);
  if (options.jpeg_quality > 0) command += " --jpeg " + std::to_string(options.jpeg_quality);
  rgb_txt << "# color images\n# " << command << "\n# timestamp filename\n";
  depth_txt << "# depth maps\n# " << command << "\n# timestamp filename\n";
  for (const auto& sp : trajectory) {
    const std::string s = stamp(sp.timestamp);
    rgb_txt << s << " rgb/" << s << color_ext << "\n";
    depth_txt << s << " depth/" << s << ".png\n";
  }
  if (!rgb_txt || !depth_txt) throw Error(out_dir + ": cannot write rgb.txt/depth.txt; check the output folder");
  const size_t mesh_vertices = writeGroundTruth(*scene, trajectory, k, out_dir);
  if (options.drift_translation_per_m > 0 || options.drift_rotation_deg_per_m > 0) {
    writeTumTrajectory(driftedTrajectory(trajectory, options.drift_translation_per_m, options.drift_rotation_deg_per_m, options.seed),
                       (fs::path(out_dir) / "drifted_trajectory.txt").string());
  }

  SequenceReport report;
  report.frames = frames;
  report.mesh_vertices = mesh_vertices;
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return report;
}

SequenceReport writeSequenceShowingProgress(SequenceOptions options, const std::string& out_dir) {
  ProgressLine line;
  const auto start = std::chrono::steady_clock::now();
  const auto rate = [&](int done) {
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return s > 0 ? done / s : 0.0;
  };
  options.on_frame = [&](int done, int total) { line.update("synth: " + frameProgress(done, total, rate(done), 0)); };
  const SequenceReport report = writeSequence(options, out_dir);
  line.finish("synth: " + frameProgress(report.frames, report.frames, rate(report.frames), 0));
  return report;
}

}  // namespace rekon::synth
