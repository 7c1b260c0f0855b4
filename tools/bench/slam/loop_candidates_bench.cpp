// loop_candidates_bench [KEYFRAMES ...]: what the loop-closure candidate
// search (LoopClosureDetector::candidates, a scan of every keyframe) costs
// as a scan grows, on keyframes 0.2 m apart along a 30 m corridor walked out
// and back again and again (every revisit adds keyframes where others are),
// the newest 10 not yet in the pose graph. Prints, per size, the wall time of
// one search and the candidates it finds within tracker.loop_search_radius.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <unordered_map>
#include <vector>

#include "rekon/tracker/loop_closure.hpp"

namespace {

constexpr double kStep = 0.2, kLength = 30.0;
constexpr int kNotInGraph = 10, kQueries = 50;

void measure(int keyframes) {
  rekon::tracker::TrackerParams params;
  rekon::tracker::LoopClosureDetector detector(params);
  std::unordered_map<int64_t, rekon::Pose> graph;
  for (int i = 0; i < keyframes; ++i) {
    const double s = std::fmod(kStep * i, 2 * kLength);
    rekon::Pose p = rekon::Pose::Identity();
    p.translation() = Eigen::Vector3d(s < kLength ? s : 2 * kLength - s, 0.0, 0.0);
    detector.addIndexed(i, p, std::nullopt);
    if (i < keyframes - kNotInGraph) graph[i] = p;
  }
  detector.updateGraph(1, graph);
  size_t found = 0;
  const auto start = std::chrono::steady_clock::now();
  for (int q = 0; q < kQueries; ++q) found += detector.candidates(keyframes - 1 - q).size();
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  std::printf("%6d keyframes: %.3f ms per search, %.1f candidates within %.1f m\n", keyframes, ms / kQueries,
              static_cast<double>(found) / kQueries, params.loop.search_radius);
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<int> sizes;
  for (int i = 1; i < argc; ++i) sizes.push_back(std::atoi(argv[i]));
  if (sizes.empty()) sizes = {1000, 5400, 20000};  // 5 400: an hour's KF keyframes at one per 20 frames
  for (int n : sizes) {
    if (n <= kQueries) {
      std::fprintf(stderr, "loop_candidates_bench: each size must be more than %d keyframes\n", kQueries);
      return 1;
    }
    measure(n);
  }
  return 0;
}
