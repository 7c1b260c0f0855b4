#include "rekon/tracker/params.hpp"

#include <cmath>
#include <sstream>
#include <string>

#include "rekon/common/error.hpp"

namespace rekon::tracker {
namespace {

void require(bool ok, const std::string& key, double value, const std::string& want) {
  if (ok) return;
  std::ostringstream text;
  text << value;  // 3 rather than 3.000000
  throw Error("tracker." + key + " = " + text.str() + " is invalid; it must be " + want);
}

}  // namespace

void AlignerParams::validate() const {
  require(finest_level >= 0 && finest_level <= 6, "finest_level", finest_level, "between 0 and 6");
  require(coarsest_level >= finest_level && coarsest_level <= 6, "coarsest_level", coarsest_level,
          "between finest_level and 6");
  require(gap_coarsest_level >= coarsest_level && gap_coarsest_level <= 6, "gap_coarsest_level", gap_coarsest_level,
          "between coarsest_level and 6");
  require(std::isfinite(gap_coarse_s) && gap_coarse_s > 0, "gap_coarse_s", gap_coarse_s, "positive");
  require(max_iterations >= 1, "max_iterations", max_iterations, "at least 1");
  require(std::isfinite(convergence_step) && convergence_step > 0, "convergence_step", convergence_step, "positive");
  require(std::isfinite(t_dof) && t_dof > 0, "t_dof", t_dof, "positive");
  require(std::isfinite(min_gradient) && min_gradient >= 0, "min_gradient", min_gradient, "zero or positive");
  require(max_pixels_per_level == 0 || max_pixels_per_level >= min_valid_pixels, "max_pixels_per_level",
          max_pixels_per_level, "0 (no budget) or at least min_valid_pixels");
  require(std::isfinite(min_depth) && min_depth > 0, "min_depth", min_depth, "positive");
  require(std::isfinite(max_depth) && max_depth > min_depth, "max_depth", max_depth, "greater than min_depth");
  require(std::isfinite(max_depth_step) && max_depth_step > 0, "max_depth_step", max_depth_step, "positive");
  require(min_valid_pixels >= 6, "min_valid_pixels", min_valid_pixels, "at least 6 (one per degree of freedom)");
  require(std::isfinite(photometric_weight) && photometric_weight >= 0 && photometric_weight <= 1 &&
              (use_depth || photometric_weight > 0),
          "loop_refine_photometric_weight (the aligner's photometric_weight)", photometric_weight,
          "in [0, 1], and above 0 without use_depth");
}

void KeyframeParams::validate() const {
  if (criterion != "entropy_ratio" && criterion != "distance")
    throw Error("tracker.keyframe_criterion = '" + criterion + "' is unknown; use entropy_ratio or distance");
  require(std::isfinite(entropy_ratio) && entropy_ratio > 0 && entropy_ratio < 1, "keyframe_entropy_ratio",
          entropy_ratio, "between 0 and 1");
  require(std::isfinite(max_translation) && max_translation > 0, "keyframe_max_translation", max_translation,
          "positive");
  require(std::isfinite(max_rotation_deg) && max_rotation_deg > 0 && max_rotation_deg <= 180,
          "keyframe_max_rotation_deg", max_rotation_deg, "in (0, 180]");
  require(std::isfinite(reuse_radius) && reuse_radius > 0, "keyframe_reuse_radius", reuse_radius, "positive (metres)");
  require(std::isfinite(reuse_angle_deg) && reuse_angle_deg > 0 && reuse_angle_deg <= 180, "keyframe_reuse_angle_deg",
          reuse_angle_deg, "in (0, 180]");
  require(reuse_candidates >= 1, "keyframe_reuse_candidates", reuse_candidates, "at least 1");
  require(reuse_exclude_recent >= 0, "keyframe_reuse_exclude_recent", reuse_exclude_recent, "0 or more");
}

void LostParams::validate() const {
  require(min_valid_depth_fraction >= 0 && min_valid_depth_fraction < 1, "lost_min_valid_depth_fraction",
          min_valid_depth_fraction, "in [0, 1)");
  require(min_mean_intensity >= 0 && min_mean_intensity < 1, "lost_min_mean_intensity", min_mean_intensity,
          "in [0, 1)");
  require(min_overlap >= 0 && min_overlap < 1, "lost_min_overlap", min_overlap, "in [0, 1)");
  require(std::isfinite(max_frame_translation) && max_frame_translation > 0, "lost_max_frame_translation",
          max_frame_translation, "positive");
  require(std::isfinite(max_frame_rotation_deg) && max_frame_rotation_deg > 0, "lost_max_frame_rotation_deg",
          max_frame_rotation_deg, "positive");
  require(std::isfinite(max_gap_s) && max_gap_s > 0, "lost_max_gap_s", max_gap_s, "positive");
  require(std::isfinite(max_intensity_sigma) && max_intensity_sigma > 0, "lost_max_intensity_sigma",
          max_intensity_sigma, "positive");
  require(std::isfinite(max_depth_sigma) && max_depth_sigma > 0, "lost_max_depth_sigma", max_depth_sigma,
          "positive");
  require(std::isfinite(residual_entropy_ratio) && residual_entropy_ratio > 0, "lost_residual_entropy_ratio",
          residual_entropy_ratio, "positive");
  require(max_lost_frames >= 1, "lost_max_frames", max_lost_frames, "at least 1");
  require(std::isfinite(relocalise_budget_ms) && relocalise_budget_ms > 0, "lost_relocalise_budget_ms", relocalise_budget_ms, "positive");
}

void LoopClosureParams::validate() const {
  require(std::isfinite(search_radius) && search_radius > 0, "loop_search_radius", search_radius, "positive");
  require(exclude_predecessors >= 1, "loop_exclude_predecessors", exclude_predecessors,
          "at least 1 (the predecessor is linked by odometry)");
  require(std::isfinite(coarse_entropy_ratio) && coarse_entropy_ratio > 0 && coarse_entropy_ratio <= 1,
          "loop_coarse_entropy_ratio", coarse_entropy_ratio, "in (0, 1]");
  require(std::isfinite(fine_entropy_ratio) && fine_entropy_ratio > 0 && fine_entropy_ratio <= 1,
          "loop_fine_entropy_ratio", fine_entropy_ratio, "in (0, 1]");
  require(min_pixel_ratio >= 0 && min_pixel_ratio < 1, "loop_min_pixel_ratio", min_pixel_ratio, "in [0, 1)");
  require(std::isfinite(max_cross_check_m) && max_cross_check_m > 0, "loop_max_cross_check", max_cross_check_m,
          "positive (metres)");
  require(std::isfinite(refine_photometric_weight) && refine_photometric_weight >= 0 && refine_photometric_weight <= 1,
          "loop_refine_photometric_weight", refine_photometric_weight, "in [0, 1] (1: no refinement)");
  require(max_candidates >= 0, "loop_max_candidates", max_candidates, "0 (all) or positive");
  require(candidates_when_behind >= 0, "loop_candidates_when_behind", candidates_when_behind, "0 (no limit) or positive");
  require(queue_capacity >= 1, "loop_queue_capacity", queue_capacity, "at least 1");
}

int AlignerParams::builtCoarsestLevel(int width, int height) const {
  int level = gap_coarsest_level;
  while (level > coarsest_level && ((width >> level) < 8 || (height >> level) < 8)) --level;
  return level;
}

void KeyframeMemoryParams::validate() const {
  require(keyframes_in_memory == 0 || keyframes_in_memory >= 2, "keyframes_in_memory", keyframes_in_memory,
          "0 (all) or at least 2 (a check aligns two keyframes)");
  require(heap_slack_mb >= 0.0, "heap_slack_mb", heap_slack_mb, ">= 0 (0: never hand freed memory back)");
  if (spill_dir.empty()) throw Error("tracker.keyframe_spill_dir is empty; it must be \"auto\" or a folder");
}

void TrackerParams::validate() const {
  aligner.validate();
  memory.validate();
  keyframe.validate();
  lost.validate();
  loop.validate();
}

TrackerParams trackerParamsFromConfig(const Config& c) {
  TrackerParams p;
  p.aligner.finest_level = c.getInt("tracker.finest_level");
  p.aligner.coarsest_level = c.getInt("tracker.coarsest_level");
  p.aligner.max_iterations = c.getInt("tracker.max_iterations");
  p.aligner.convergence_step = c.getDouble("tracker.convergence_step");
  p.aligner.t_dof = c.getDouble("tracker.t_dof");
  p.aligner.min_gradient = c.getDouble("tracker.min_gradient");
  p.aligner.max_pixels_per_level = c.getInt("tracker.max_pixels_per_level");
  p.aligner.min_depth = c.getDouble("tracker.min_depth");
  p.aligner.max_depth = c.getDouble("tracker.max_depth");
  p.aligner.max_depth_step = c.getDouble("tracker.max_depth_step");
  p.aligner.min_valid_pixels = c.getInt("tracker.min_valid_pixels");
  p.aligner.use_depth = c.getBool("tracker.use_depth");
  p.aligner.gap_coarsest_level = c.getInt("tracker.gap_coarsest_level");
  p.aligner.gap_coarse_s = c.getDouble("tracker.gap_coarse_s");
  p.keyframe.criterion = c.getString("tracker.keyframe_criterion");
  p.keyframe.entropy_ratio = c.getDouble("tracker.keyframe_entropy_ratio");
  p.keyframe.max_translation = c.getDouble("tracker.keyframe_max_translation");
  p.keyframe.max_rotation_deg = c.getDouble("tracker.keyframe_max_rotation_deg");
  p.keyframe.reuse = c.getBool("tracker.keyframe_reuse");
  p.keyframe.reuse_radius = c.getDouble("tracker.keyframe_reuse_radius");
  p.keyframe.reuse_angle_deg = c.getDouble("tracker.keyframe_reuse_angle_deg");
  p.keyframe.reuse_candidates = c.getInt("tracker.keyframe_reuse_candidates");
  p.keyframe.reuse_exclude_recent = c.getInt("tracker.keyframe_reuse_exclude_recent");
  p.lost.min_valid_depth_fraction = c.getDouble("tracker.lost_min_valid_depth_fraction");
  p.lost.min_mean_intensity = c.getDouble("tracker.lost_min_mean_intensity");
  p.lost.min_overlap = c.getDouble("tracker.lost_min_overlap");
  p.lost.max_frame_translation = c.getDouble("tracker.lost_max_frame_translation");
  p.lost.max_frame_rotation_deg = c.getDouble("tracker.lost_max_frame_rotation_deg");
  p.lost.max_gap_s = c.getDouble("tracker.lost_max_gap_s");
  p.lost.max_intensity_sigma = c.getDouble("tracker.lost_max_intensity_sigma");
  p.lost.max_depth_sigma = c.getDouble("tracker.lost_max_depth_sigma");
  p.lost.residual_entropy_ratio = c.getDouble("tracker.lost_residual_entropy_ratio");
  p.lost.max_lost_frames = c.getInt("tracker.lost_max_frames");
  p.lost.relocalise_budget_ms = c.getDouble("tracker.lost_relocalise_budget_ms");
  p.memory.keyframes_in_memory = c.getInt("tracker.keyframes_in_memory");
  p.memory.spill_dir = c.getString("tracker.keyframe_spill_dir");
  p.memory.heap_slack_mb = c.getDouble("tracker.heap_slack_mb");
  p.loop.enabled = c.getBool("tracker.loop_closure");
  p.loop.search_radius = c.getDouble("tracker.loop_search_radius");
  p.loop.exclude_predecessors = c.getInt("tracker.loop_exclude_predecessors");
  p.loop.coarse_entropy_ratio = c.getDouble("tracker.loop_coarse_entropy_ratio");
  p.loop.fine_entropy_ratio = c.getDouble("tracker.loop_fine_entropy_ratio");
  p.loop.min_pixel_ratio = c.getDouble("tracker.loop_min_pixel_ratio");
  p.loop.max_cross_check_m = c.getDouble("tracker.loop_max_cross_check");
  p.loop.both_directions = c.getBool("tracker.loop_both_directions");
  p.loop.refine_photometric_weight = c.getDouble("tracker.loop_refine_photometric_weight");
  p.loop.max_candidates = c.getInt("tracker.loop_max_candidates");
  const std::string when_behind = c.getString("tracker.loop_when_behind");
  if (when_behind != "hold" && when_behind != "fewer")
    throw Error("tracker.loop_when_behind = '" + when_behind + "' is unknown; use hold or fewer");
  p.loop.when_behind = when_behind == "hold" ? LoopClosureParams::WhenBehind::kHold : LoopClosureParams::WhenBehind::kFewer;
  p.loop.candidates_when_behind = c.getInt("tracker.loop_candidates_when_behind");
  p.loop.queue_capacity = c.getInt("tracker.loop_queue_capacity");
  p.validate();
  return p;
}

}  // namespace rekon::tracker
