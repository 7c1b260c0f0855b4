#pragma once
// Tunables of the pose-graph optimiser (config section `optimiser:`), with
// named defaults. Read once per service by optimiserParamsFromConfig.
#include <string>

namespace rekon {
class Config;
}

namespace rekon::optimiser {

enum class RobustLoss { Cauchy, Huber, None };

// How the normal equations are solved. Both minimise the same cost with the
// same residuals and Jacobians (relative_pose_cost.hpp).
//  BlockCholesky: Levenberg-Marquardt on a sparse Cholesky of 6x6 blocks,
//    symbolic analysis kept between solves (about 3x faster than Ceres here).
//  Ceres: Ceres' Levenberg-Marquardt with SPARSE_NORMAL_CHOLESKY (CHOLMOD),
//    the reference the tests compare BlockCholesky against.
enum class Solver { BlockCholesky, Ceres };

struct PoseGraphParams {
  // Robust loss on loop edges only (odometry is trusted as the tracker's
  // Gaussian estimate). The scale is in whitened units: a loop edge whose
  // sqrt(chi2) exceeds it starts losing weight.
  static constexpr double kDefaultLoopLossScale = 3.0;
  // After optimising, a loop edge with chi2 = r^T I r above this is an outlier
  // and removed. 22.46 is the 99.9 % quantile of chi2 with 6 degrees of
  // freedom: of 4 000 correct loop edges about 4 go.
  static constexpr double kDefaultLoopOutlierChi2 = 22.46;
  // Background optimisations are bounded so that a new constraint waits at
  // most about one optimisation.
  static constexpr int kDefaultMaxIterations = 10;
  static constexpr double kDefaultMaxSolverTimeS = 0.2;
  // A background optimisation stops once an iteration lowers the cost by less
  // than this fraction: the next constraint will move the poses again anyway.
  static constexpr double kDefaultFunctionTolerance = 1e-3;
  // The final optimisation at the end of a run may take longer, and converges
  // to Ceres' default tolerance.
  static constexpr double kDefaultFinalFunctionTolerance = 1e-6;
  static constexpr int kDefaultFinalMaxIterations = 100;
  // Remove-and-re-optimise rounds per optimisation at most.
  static constexpr int kDefaultOutlierRounds = 3;
  // Keyframe culling (services/optimiser/README.md, "Memory"): a keyframe
  // judged once this many newer keyframes have arrived (the tracker's loop
  // checks skip the last 20 keyframes, so by then its own loop edges are in
  // the graph and optimised) is culled onto a kept keyframe at least this
  // many keyframes older (a revisit) that an edge links it to and that lies
  // within cull_radius_m and cull_angle_deg.
  static constexpr int kCullWindow = 20;

  Solver solver = Solver::BlockCholesky;
  RobustLoss loop_loss = RobustLoss::Cauchy;
  double loop_loss_scale = kDefaultLoopLossScale;
  double loop_outlier_chi2 = kDefaultLoopOutlierChi2;
  int max_iterations = kDefaultMaxIterations;
  double max_solver_time_s = kDefaultMaxSolverTimeS;
  double function_tolerance = kDefaultFunctionTolerance;
  int final_max_iterations = kDefaultFinalMaxIterations;
  double final_function_tolerance = kDefaultFinalFunctionTolerance;
  int outlier_rounds = kDefaultOutlierRounds;
  // 0: no culling (the graph keeps every keyframe). Set by config/default.yaml.
  double cull_radius_m = 0.0;
  double cull_angle_deg = 0.0;
  // With culling: the most kept keyframes a kept keyframe is paired with by
  // moved loop edges (a revisit's, culled onto it); past that a moved edge
  // that would pair it with one more is re-routed onto the existing pair
  // whose other end is nearest to its own (within kRerouteRadiusM), or
  // dropped. 0: no cap. Set by config/default.yaml.
  int loop_neighbours_max = 0;
  static constexpr double kRerouteRadiusM = 1.0;

  // Throws rekon::Error naming the first invalid key.
  void validate() const;
};

struct OptimiserServiceParams {
  // Every arriving information matrix is multiplied by this. Dense alignment
  // treats its pixels as independent and so claims far more certainty than
  // it has: against ground truth, the tracker's odometry constraints have a
  // median chi2 of about 1e5 (7-Scenes loop, 85 edges; TUM fr3 teddy, 16
  // edges) where calibrated ones would have 5.35 (6 dof). A uniform scale
  // would leave a plain least-squares optimum unchanged, but loop edges go
  // through the Cauchy loss and the outlier test, so it moves the optimum
  // (7-Scenes, 2026-11-22: ATE 0.0483 m at 1e-5, 0.0445 m at 2e-4, which removed
  // 48 loop edges; services/optimiser/README.md):
  // it makes the robust loss scale and the outlier chi2 mean what they say. 1e-5 rather than 5e-5
  // because the drift between keyframes is correlated: on the 7-Scenes loop
  // (86 keyframes, 142 loop edges from ground truth with 1 cm / 5 mrad noise)
  // 5e-5 removed 60 correct loop edges, 1e-5 removed 2, and still removed
  // all of 10 loop edges made 30 cm wrong.
  static constexpr double kDefaultInformationScale = 1e-5;

  // The service's final graph update and done message are sent this many
  // times, this far apart: UDP multicast may drop one.
  static constexpr int kDefaultFinalRepeats = 3;
  static constexpr int kDefaultFinalRepeatGapMs = 50;

  PoseGraphParams graph;
  double information_scale = kDefaultInformationScale;
  int final_repeats = kDefaultFinalRepeats;
  int final_repeat_gap_ms = kDefaultFinalRepeatGapMs;
  // The optimisation thread's nice value (0-19): above 0 its solves yield
  // the cores to the frame source and to tracking (rekon run sets 10 behind
  // a live source, as for the mapper).
  int nice = 0;

  void validate() const;
};

RobustLoss robustLossFromString(const std::string& name);
const char* toString(RobustLoss loss);
Solver solverFromString(const std::string& name);
const char* toString(Solver solver);

// Reads the `optimiser:` section; throws rekon::Error for invalid values.
OptimiserServiceParams optimiserParamsFromConfig(const Config& config);

}  // namespace rekon::optimiser
