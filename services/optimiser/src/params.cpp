#include "rekon/optimiser/params.hpp"

#include <cmath>

#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/priority.hpp"

namespace rekon::optimiser {
namespace {

void require(bool ok, const std::string& key, double value, const std::string& want) {
  if (!ok) throw Error("optimiser." + key + " = " + std::to_string(value) + " is invalid; it must be " + want);
}

}  // namespace

void PoseGraphParams::validate() const {
  require(std::isfinite(loop_loss_scale) && loop_loss_scale > 0, "loop_loss_scale", loop_loss_scale, "positive");
  require(std::isfinite(loop_outlier_chi2) && loop_outlier_chi2 > 0, "loop_outlier_chi2", loop_outlier_chi2,
          "positive");
  require(max_iterations >= 1, "max_iterations", max_iterations, "at least 1");
  require(std::isfinite(max_solver_time_s) && max_solver_time_s > 0, "max_solver_time_s", max_solver_time_s,
          "positive");
  require(std::isfinite(function_tolerance) && function_tolerance > 0 && function_tolerance < 1, "function_tolerance",
          function_tolerance, "in (0, 1)");
  require(std::isfinite(final_function_tolerance) && final_function_tolerance > 0 && final_function_tolerance < 1,
          "final_function_tolerance", final_function_tolerance, "in (0, 1)");
  require(final_max_iterations >= 1, "final_max_iterations", final_max_iterations, "at least 1");
  require(outlier_rounds >= 0, "outlier_rounds", outlier_rounds, "zero (keep every loop edge) or more");
  require(std::isfinite(cull_radius_m) && cull_radius_m >= 0, "cull_radius_m", cull_radius_m, "zero (no culling) or more");
  require(std::isfinite(cull_angle_deg) && cull_angle_deg >= 0 && cull_angle_deg <= 180, "cull_angle_deg",
          cull_angle_deg, "between 0 and 180");
  require(loop_neighbours_max >= 0, "loop_neighbours_max", loop_neighbours_max, "zero (no cap) or more");
}

void OptimiserServiceParams::validate() const {
  graph.validate();
  require(std::isfinite(information_scale) && information_scale > 0, "information_scale", information_scale,
          "positive");
  require(final_repeats >= 1 && final_repeats <= 100, "final_repeats", final_repeats, "between 1 and 100");
  require(final_repeat_gap_ms >= 0 && final_repeat_gap_ms <= 10000, "final_repeat_gap_ms", final_repeat_gap_ms,
          "between 0 and 10000");
  requireNice(nice, "optimiser.nice");
}

RobustLoss robustLossFromString(const std::string& name) {
  if (name == "cauchy") return RobustLoss::Cauchy;
  if (name == "huber") return RobustLoss::Huber;
  if (name == "none") return RobustLoss::None;
  throw Error("optimiser.loop_loss = '" + name + "' is unknown; use cauchy, huber or none");
}

const char* toString(RobustLoss loss) {
  switch (loss) {
    case RobustLoss::Cauchy: return "cauchy";
    case RobustLoss::Huber: return "huber";
    case RobustLoss::None: return "none";
  }
  return "?";
}

Solver solverFromString(const std::string& name) {
  if (name == "block_cholesky") return Solver::BlockCholesky;
  if (name == "ceres") return Solver::Ceres;
  throw Error("optimiser.solver = '" + name + "' is unknown; use block_cholesky or ceres");
}

const char* toString(Solver solver) {
  switch (solver) {
    case Solver::BlockCholesky: return "block_cholesky";
    case Solver::Ceres: return "ceres";
  }
  return "?";
}

OptimiserServiceParams optimiserParamsFromConfig(const Config& config) {
  OptimiserServiceParams p;
  p.graph.solver = solverFromString(config.getString("optimiser.solver"));
  p.graph.loop_loss = robustLossFromString(config.getString("optimiser.loop_loss"));
  p.graph.loop_loss_scale = config.getDouble("optimiser.loop_loss_scale");
  p.graph.loop_outlier_chi2 = config.getDouble("optimiser.loop_outlier_chi2");
  p.graph.outlier_rounds = config.getInt("optimiser.outlier_rounds");
  p.graph.max_iterations = config.getInt("optimiser.max_iterations");
  p.graph.max_solver_time_s = config.getDouble("optimiser.max_solver_time_s");
  p.graph.function_tolerance = config.getDouble("optimiser.function_tolerance");
  p.graph.final_max_iterations = config.getInt("optimiser.final_max_iterations");
  p.graph.final_function_tolerance = config.getDouble("optimiser.final_function_tolerance");
  p.graph.cull_radius_m = config.getDouble("optimiser.cull_radius_m");
  p.graph.cull_angle_deg = config.getDouble("optimiser.cull_angle_deg");
  p.graph.loop_neighbours_max = config.getInt("optimiser.loop_neighbours_max");
  p.information_scale = config.getDouble("optimiser.information_scale");
  p.final_repeats = config.getInt("optimiser.final_repeats");
  p.final_repeat_gap_ms = config.getInt("optimiser.final_repeat_gap_ms");
  p.nice = config.getInt("optimiser.nice");
  p.validate();
  return p;
}

}  // namespace rekon::optimiser
