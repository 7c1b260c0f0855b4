// Pose-graph optimisation speed on one core (issue 5: 1 000 keyframes and
// 5 000 edges in at most 100 ms). Prints numbers; not a test.
//   rekon_optimiser_benchmark [KEYFRAMES] [EDGES] [REPEATS] [block_cholesky|ceres]
// Run it pinned to one core: taskset -c 0 rekon_optimiser_benchmark. Prints
// wall time and the optimising thread's CPU time (on a shared, loaded
// machine the CPU time is the figure to compare).
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/optimiser/synthetic_graph.hpp"

using namespace rekon::optimiser;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

void addAll(PoseGraph& graph, const SyntheticGraph& g, size_t constraints) {
  for (size_t i = 0; i < g.initial.size(); ++i) graph.addKeyframe(static_cast<int64_t>(i), g.initial[i]);
  for (size_t i = 0; i < constraints; ++i) graph.addConstraint(g.constraints[i]);
}

}  // namespace

int main(int argc, char** argv) {
  const int keyframes = argc > 1 ? std::atoi(argv[1]) : 1000;
  const int edges = argc > 2 ? std::atoi(argv[2]) : 5000;
  const int repeats = argc > 3 ? std::atoi(argv[3]) : 5;
  PoseGraphParams params;  // defaults: Cauchy on loops, bounded background budget
  try {
    if (argc > 4) params.solver = solverFromString(argv[4]);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  if (keyframes < 2 || edges < keyframes - 1 || repeats < 1) {
    std::fprintf(stderr, "usage: rekon_optimiser_benchmark [KEYFRAMES>=2] [EDGES>=KEYFRAMES-1] [REPEATS>=1]\n");
    return 1;
  }
  SyntheticGraphSpec spec;
  spec.keyframes = keyframes;
  spec.laps = 5;
  spec.loop_edges = edges - (keyframes - 1);
  spec.seed = 7;
  const SyntheticGraph g = makeSyntheticGraph(spec);
  std::printf("graph: %d keyframes, %d odometry + %d loop edges, 5 laps of a %.1f m circle, noise %.1f mm / %.2f deg per edge\n",
              keyframes, keyframes - 1, spec.loop_edges, spec.radius_m, 1e3 * spec.sigma_translation_m,
              spec.sigma_rotation_rad * 180.0 / 3.14159265358979);
  std::printf("solver: %s\n", toString(params.solver));

  // Cold: from chained odometry (drift of several laps), full final budget.
  std::vector<double> cold_ms, cold_cpu;
  OptimiseReport cold{};
  double before = 0, after = 0;
  for (int r = 0; r < repeats; ++r) {
    PoseGraph graph(params);
    addAll(graph, g, g.constraints.size());
    before = maxTranslationError(g.truth, graph.poses());
    cold = graph.optimise(true);
    after = maxTranslationError(g.truth, graph.poses());
    cold_ms.push_back(cold.ms);
    cold_cpu.push_back(cold.cpu_ms);
  }
  std::printf("cold start (odometry initial, final=true): median %.1f ms wall, %.1f ms CPU over %d runs; %d iterations "
              "in %d solve(s), %d loop edges removed; max position error %.3f m -> %.4f m\n",
              median(cold_ms), median(cold_cpu), repeats, cold.iterations, cold.rounds, cold.loop_edges_removed, before, after);

  // Warm: the graph of keyframes below `first_new` is optimised; then the
  // keyframes from `first_new` on arrive with all their edges and one bounded
  // background optimisation runs (what the service does after each batch).
  const auto warm = [&](int first_new, const char* what) {
    std::vector<double> ms, cpu;
    OptimiseReport report{};
    double error = 0;
    for (int r = 0; r < repeats; ++r) {
      PoseGraph graph(params);
      for (int i = 0; i < first_new; ++i) graph.addKeyframe(i, g.initial[static_cast<size_t>(i)]);
      for (const Constraint& c : g.constraints) {
        if (c.from_id < first_new && c.to_id < first_new) graph.addConstraint(c);
      }
      graph.optimise(true);
      for (int i = first_new; i < keyframes; ++i) graph.addKeyframe(i, g.initial[static_cast<size_t>(i)]);
      int added = 0;
      for (const Constraint& c : g.constraints) {
        if (c.from_id >= first_new || c.to_id >= first_new) {
          graph.addConstraint(c);
          ++added;
        }
      }
      report = graph.optimise(false);
      ms.push_back(report.ms);
      cpu.push_back(report.cpu_ms);
      error = maxTranslationError(g.truth, graph.poses());
      if (r == 0) std::printf("  (%s: %d new edges)\n", what, added);
    }
    std::printf("warm start, %s, background budget: median %.1f ms wall, %.1f ms CPU over %d runs; %d iterations in "
                "%d solve(s); max position error %.4f m\n",
                what, median(ms), median(cpu), repeats, report.iterations, report.rounds, error);
  };
  warm(keyframes - 1, "one new keyframe with its odometry and loop edges");
  warm(keyframes - keyframes / 10, "the last 10 % of keyframes at once");
  std::printf("goal: <= 100 ms for 1 000 keyframes and 5 000 edges on one core\n");
  return 0;
}
