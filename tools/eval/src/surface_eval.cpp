#include "rekon/eval/surface_eval.hpp"

#include <fmt/format.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <random>
#include <thread>

#include "closest_point.hpp"
#include "rekon/common/error.hpp"

namespace rekon::eval {
namespace {

// Points uniformly distributed over the area of the mesh (its vertices when it has no triangles).
std::vector<Eigen::Vector3f> sampleSurface(const Mesh& mesh, const SurfaceEvalOptions& options) {
  if (mesh.triangles.empty()) return mesh.vertices;
  std::vector<double> cumulative(mesh.triangles.size());
  double area = 0.0;
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const auto& t = mesh.triangles[i];
    const Eigen::Vector3d a = mesh.vertices[static_cast<size_t>(t[0])].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[static_cast<size_t>(t[1])].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[static_cast<size_t>(t[2])].cast<double>();
    area += 0.5 * (b - a).cross(c - a).norm();
    cumulative[i] = area;
  }
  size_t n = options.reference_samples;
  if (n == 0) {
    n = static_cast<size_t>(area * SurfaceEvalOptions::kDefaultSamplesPerM2);
    n = std::clamp(n, SurfaceEvalOptions::kMinSamples, SurfaceEvalOptions::kMaxSamples);
  }
  if (area <= 0.0) return mesh.vertices;  // only degenerate triangles: fall back to the vertices
  std::mt19937_64 rng(options.seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::vector<Eigen::Vector3f> out;
  out.reserve(n);
  for (size_t k = 0; k < n; ++k) {
    const double target = uni(rng) * area;
    const size_t i = std::min(static_cast<size_t>(std::upper_bound(cumulative.begin(), cumulative.end(), target) - cumulative.begin()),
                              cumulative.size() - 1);
    const auto& t = mesh.triangles[i];
    const double r1 = std::sqrt(uni(rng)), r2 = uni(rng);
    const Eigen::Vector3d a = mesh.vertices[static_cast<size_t>(t[0])].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[static_cast<size_t>(t[1])].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[static_cast<size_t>(t[2])].cast<double>();
    out.push_back(((1 - r1) * a + r1 * (1 - r2) * b + r1 * r2 * c).cast<float>());
  }
  return out;
}

struct DistanceStats {
  double mean = 0, within_1cm = 0, within_2cm = 0, median = 0;
};

int threadCount(int requested) {
  return requested > 0 ? requested : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

std::vector<float> distancesTo(const std::vector<Eigen::Vector3f>& points, const ClosestPointIndex& index, double cap,
                               int threads) {
  std::vector<float> d(points.size());
  std::atomic<size_t> next{0};
  constexpr size_t kChunk = 4096;
  auto work = [&] {
    for (;;) {
      const size_t start = next.fetch_add(kChunk);
      if (start >= points.size()) return;
      const size_t end = std::min(points.size(), start + kChunk);
      for (size_t i = start; i < end; ++i) d[i] = index.distance(points[i], static_cast<float>(cap));
    }
  };
  std::vector<std::thread> pool;
  for (int i = 1; i < threads; ++i) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
  return d;
}

DistanceStats distances(const std::vector<Eigen::Vector3f>& points, const ClosestPointIndex& index, double cap, int threads) {
  std::vector<float> d = distancesTo(points, index, cap, threads);
  DistanceStats s;
  if (d.empty()) return s;
  double sum = 0;
  size_t n1 = 0, n2 = 0;
  for (float x : d) {
    sum += std::min(static_cast<double>(x), cap);
    n1 += x <= 0.01f;
    n2 += x <= 0.02f;
  }
  const double n = static_cast<double>(d.size());
  s.mean = sum / n;
  s.within_1cm = static_cast<double>(n1) / n;
  s.within_2cm = static_cast<double>(n2) / n;
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  s.median = d[d.size() / 2];
  return s;
}

}  // namespace

std::vector<float> distancesToSurface(const std::vector<Eigen::Vector3f>& points, const Mesh& surface, double cap_m,
                                      int threads) {
  if (!(cap_m > 0)) throw Error("the distance cap must be positive, got " + fmt::format("{}", cap_m));
  const ClosestPointIndex index(surface);
  return distancesTo(points, index, cap_m, threadCount(threads));
}

SurfaceErrors evaluateSurface(const Mesh& mesh, const Mesh& reference, const SurfaceEvalOptions& options) {
  if (mesh.vertices.empty()) throw Error("the evaluated mesh has no vertices; nothing to compare");
  if (reference.vertices.empty()) throw Error("the reference mesh has no vertices; give the ground-truth mesh");
  if (!(options.cap_m > 0)) throw Error("the distance cap must be positive, got " + fmt::format("{}", options.cap_m));
  const int threads = threadCount(options.threads);
  SurfaceErrors r;
  r.cap_m = options.cap_m;
  r.mesh_vertices = mesh.vertices.size();
  {
    const ClosestPointIndex ref_index(reference);
    const DistanceStats corr = distances(mesh.vertices, ref_index, options.cap_m, threads);
    r.corr_m = corr.mean;
    r.corr_within_1cm = corr.within_1cm;
    r.corr_within_2cm = corr.within_2cm;
    r.corr_median_m = corr.median;
  }
  const std::vector<Eigen::Vector3f> samples = sampleSurface(reference, options);
  r.reference_samples = samples.size();
  const ClosestPointIndex mesh_index(mesh);
  const DistanceStats compl_ = distances(samples, mesh_index, options.cap_m, threads);
  r.compl_m = compl_.mean;
  r.compl_within_1cm = compl_.within_1cm;
  r.compl_within_2cm = compl_.within_2cm;
  r.compl_median_m = compl_.median;
  return r;
}

}  // namespace rekon::eval
