// A run's pose graph again, in one process: the keyframes and constraints of
// an optimiser journal (OUT/optimiser_journal.rkj) applied in arrival order,
// optimised after each keyframe's batch as the service does, then the final
// optimisation and the trajectory of the journal's tracked frames. Prints the
// graph's size, the heap in use and the mean solve time every EVERY keyframes
// (issue 49: what grows with time). Prints numbers; not a test.
//   rekon_optimiser_replay JOURNAL TRAJECTORY_OUT [CULL_RADIUS_M] [CULL_ANGLE_DEG] [EVERY] [RESTART_AT,...] [LOOPS_OUT]
//                          [loop_neighbours_max=N]
// RESTART_AT: keyframe counts at which the optimiser is killed and restarted,
// as rekon run does (issue 48): a new graph gets everything so far at once
// (rebuildFromJournal), then the replay goes on. LOOPS_OUT: the loop edges
// the final graph keeps, "from to chi2" per line (with culling, between the
// kept keyframes their ends were moved to).
#include <malloc.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <variant>
#include <vector>

#include "graph_worker.hpp"
#include "journal.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/optimiser/graph_messages.hpp"

using namespace rekon::optimiser;

namespace {

double heapMb() { return static_cast<double>(mallinfo2().uordblks) / (1024.0 * 1024.0); }

struct Window {
  double ms = 0.0;
  int solves = 0;
};

void printRow(const GraphWorker& worker, size_t applied, Window& window) {
  const PoseGraph& g = worker.graph();
  std::printf("%6zu items  %5zu keyframes (%5zu culled)  %6zu edges (%4zu loop)  heap %6.2f MB  solve %6.2f ms mean\n",
              applied, g.numKeyframes(), g.numCulled(), g.numConstraints(), g.numLoopEdges(), heapMb(),
              window.solves > 0 ? window.ms / window.solves : 0.0);
  window = {};
}

}  // namespace

int main(int raw_argc, char** raw_argv) {
  // Positional arguments, and the one option (loop_neighbours_max=N, as optimiser.loop_neighbours_max).
  std::vector<char*> positional;
  int loop_neighbours_max = 0;
  for (int i = 0; i < raw_argc; ++i) {
    const std::string arg = raw_argv[i];
    if (arg.rfind("loop_neighbours_max=", 0) == 0)
      loop_neighbours_max = std::atoi(arg.c_str() + arg.find('=') + 1);
    else
      positional.push_back(raw_argv[i]);
  }
  const int argc = static_cast<int>(positional.size());
  char** argv = positional.data();
  if (argc < 3) {
    std::fprintf(stderr, "usage: rekon_optimiser_replay JOURNAL TRAJECTORY_OUT [CULL_RADIUS_M] [CULL_ANGLE_DEG] [EVERY] [RESTART_AT,...] [LOOPS_OUT] [loop_neighbours_max=N]\n");
    return 1;
  }
  try {
    PoseGraphParams params;
    params.cull_radius_m = argc > 3 ? std::atof(argv[3]) : 0.0;
    params.cull_angle_deg = argc > 4 ? std::atof(argv[4]) : 15.0;
    params.loop_neighbours_max = loop_neighbours_max;
    const size_t every = argc > 5 ? static_cast<size_t>(std::atoi(argv[5])) : 100;
    std::set<size_t> restarts;
    std::istringstream restart_list(argc > 6 ? argv[6] : "");
    for (std::string at; std::getline(restart_list, at, ',');) restarts.insert(std::stoul(at));
    const JournalContents journal = readJournal(argv[1]);
    auto worker_ptr = std::make_unique<GraphWorker>(params);
    Window window;
    size_t keyframes = 0;
    bool new_edges = false;
    for (size_t i = 0; i < journal.items.size(); ++i) {
      const bool keyframe = std::holds_alternative<KeyframeIn>(journal.items[i]);
      if (keyframe && restarts.count(keyframes) > 0) {
        std::printf("restart after %zu keyframes: a new graph gets the %zu items before at once\n", keyframes, i);
        worker_ptr = std::make_unique<GraphWorker>(params);
        worker_ptr->apply({journal.items.begin(), journal.items.begin() + static_cast<std::ptrdiff_t>(i)});
        new_edges = true;
      }
      GraphWorker& worker = *worker_ptr;
      new_edges |= worker.apply({journal.items[i]});
      const bool batch_ends = i + 1 == journal.items.size() || std::holds_alternative<KeyframeIn>(journal.items[i + 1]);
      if (keyframe && ++keyframes % every == 0)
        printRow(worker, i + 1, window);
      if (batch_ends && new_edges) {
        new_edges = false;
        const auto start = std::chrono::steady_clock::now();
        worker.optimise(false, -1);
        window.ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        ++window.solves;
      }
    }
    GraphWorker& worker = *worker_ptr;
    worker.optimise(true, -1);
    printRow(worker, journal.items.size(), window);
    const PoseGraph& g = worker.graph();
    std::printf("merged edges %zu, dropped by culling %zu, re-routed %zu, dropped by the cap %zu, outliers removed %zu\n",
                g.edgesMerged(), g.edgesDroppedByCulling(), g.edgesRerouted(), g.edgesDroppedByCap(), g.loopEdgesRemoved());
    if (argc > 7) {
      std::ofstream loops(argv[7]);
      const std::vector<Constraint> kept = worker.graph().loopEdges();
      const std::vector<double> chi2 = worker.graph().loopChi2();
      for (size_t i = 0; i < kept.size(); ++i) loops << kept[i].from_id << ' ' << kept[i].to_id << ' ' << chi2[i] << '\n';
    }
    size_t missing = 0;
    writeTumTrajectory(frameTrajectory(worker.graph(), journal.frames, &missing), argv[2]);
    std::printf("wrote %zu frames (%zu missing a keyframe) to %s\n", journal.frames.size() - missing, missing, argv[2]);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
