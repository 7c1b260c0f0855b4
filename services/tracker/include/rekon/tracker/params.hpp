#pragma once
// Every tunable of the tracker, with its named default. `tracker:` in
// config/default.yaml documents each key; trackerParamsFromConfig reads them.
#include <string>

#include "rekon/common/config.hpp"

namespace rekon::tracker {

// How the dense aligner selects pixels and iterates.
struct AlignerParams {
  static constexpr int kDefaultFinestLevel = 1;    // 320x240 of a 640x480 frame
  static constexpr int kDefaultCoarsestLevel = 3;  // 80x60
  static constexpr int kDefaultMaxIterations = 20;
  static constexpr double kDefaultConvergenceStep = 1e-4;
  static constexpr double kDefaultTDistributionDof = 5.0;
  static constexpr double kDefaultMinGradient = 0.01;
  static constexpr int kDefaultMaxPixelsPerLevel = 20000;
  static constexpr double kDefaultMinDepth = 0.1;
  static constexpr double kDefaultMaxDepth = 6.0;
  static constexpr double kDefaultMaxDepthStep = 0.1;
  static constexpr int kDefaultMinValidPixels = 150;
  static constexpr bool kDefaultUseDepth = true;
  static constexpr double kDefaultPhotometricWeight = 1.0;
  static constexpr int kDefaultGapCoarsestLevel = 4;  // 40x30
  static constexpr double kDefaultGapCoarseS = 0.1;

  int finest_level = kDefaultFinestLevel;
  int coarsest_level = kDefaultCoarsestLevel;
  int max_iterations = kDefaultMaxIterations;        // per pyramid level
  double convergence_step = kDefaultConvergenceStep;  // stop a level when |increment| falls below
  double t_dof = kDefaultTDistributionDof;             // nu of the bivariate t-distribution
  // Keyframe pixels whose intensity gradient (intensity 0..1 per pixel) is
  // smaller than this are skipped: they carry almost no information.
  double min_gradient = kDefaultMinGradient;
  // Budget of keyframe pixels per level (0 = no budget): above it only the
  // strongest intensity gradients are kept.
  int max_pixels_per_level = kDefaultMaxPixelsPerLevel;
  double min_depth = kDefaultMinDepth;  // metres; depth outside [min, max] counts as missing
  double max_depth = kDefaultMaxDepth;
  // Relative depth change between neighbouring pixels above which a pixel sits
  // on an occlusion edge: its depth gradient is meaningless, so it is skipped.
  double max_depth_step = kDefaultMaxDepthStep;
  int min_valid_pixels = kDefaultMinValidPixels;  // fewer warped pixels at a level: alignment fails
  bool use_depth = kDefaultUseDepth;              // false: photometric residual only
  // Weight of the whitened photometric rows against the geometric ones (1 =
  // DVO's joint t-distribution; 0 = geometric only, which needs use_depth).
  // The tracker keeps 1; the loop detector's refinement lowers it (see
  // LoopClosureParams::refine_photometric_weight).
  double photometric_weight = kDefaultPhotometricWeight;
  // A frame more than gap_coarse_s after the last good one (frames dropped
  // or skipped) starts aligning on gap_coarsest_level instead: its motion
  // from the prediction is larger, and a coarser level widens the basin.
  int gap_coarsest_level = kDefaultGapCoarsestLevel;
  double gap_coarse_s = kDefaultGapCoarseS;

  // The coarsest level pyramids and keyframe references are built with for
  // an image of `width` x `height`: gap_coarsest_level where it still has
  // 8x8 pixels, never below coarsest_level.
  int builtCoarsestLevel(int width, int height) const;

  // Throws rekon::Error naming the key for a value out of range.
  void validate() const;
};

// When a new DVO keyframe starts.
struct KeyframeParams {
  static constexpr const char* kDefaultCriterion = "entropy_ratio";
  static constexpr double kDefaultEntropyRatio = 0.91;
  static constexpr double kDefaultMaxTranslation = 0.2;
  static constexpr double kDefaultMaxRotationDeg = 15.0;
  static constexpr bool kDefaultReuse = false;
  static constexpr double kDefaultReuseRadius = 0.3;
  static constexpr double kDefaultReuseAngleDeg = 20.0;
  static constexpr int kDefaultReuseCandidates = 2;
  static constexpr int kDefaultReuseExcludeRecent = 20;

  // "entropy_ratio" (Kerl et al. IROS 2013, plus the distance limits) or
  // "distance" (the distance limits only).
  std::string criterion = kDefaultCriterion;
  double entropy_ratio = kDefaultEntropyRatio;
  double max_translation = kDefaultMaxTranslation;  // metres from the keyframe
  double max_rotation_deg = kDefaultMaxRotationDeg;
  // Keyframe reuse on revisit (issue 49): a due keyframe is first looked for
  // among the existing ones whose camera centre lies within reuse_radius
  // metres and whose orientation within reuse_angle_deg of the frame's pose
  // (nearest first, at most reuse_candidates); the first that validates as a
  // loop closure does (LoopClosureDetector::check) becomes the reference
  // instead of a new keyframe, and the edge from it to the keyframe the frame
  // was tracked against goes out as a loop edge (robust loss). Revisits then
  // add no keyframes and no loop edges: the graph grows with the space.
  bool reuse = kDefaultReuse;
  double reuse_radius = kDefaultReuseRadius;
  double reuse_angle_deg = kDefaultReuseAngleDeg;
  int reuse_candidates = kDefaultReuseCandidates;
  // The newest this many keyframes are never reused (0: any but the one
  // tracked against): only revisits after a while switch.
  int reuse_exclude_recent = kDefaultReuseExcludeRecent;

  void validate() const;
};

// When a frame counts as lost.
struct LostParams {
  static constexpr double kDefaultMinValidDepthFraction = 0.05;
  static constexpr double kDefaultMinMeanIntensity = 0.02;
  static constexpr double kDefaultMinOverlap = 0.2;
  static constexpr double kDefaultMaxFrameTranslation = 0.3;
  static constexpr double kDefaultMaxFrameRotationDeg = 30.0;
  static constexpr double kDefaultMaxGapS = 1.0;
  static constexpr double kDefaultMaxIntensitySigma = 0.2;
  static constexpr double kDefaultMaxDepthSigma = 0.3;
  static constexpr double kDefaultResidualEntropyRatio = 0.75;
  static constexpr int kDefaultMaxLostFrames = 30;
  static constexpr double kDefaultRelocaliseBudgetMs = 100.0;

  double min_valid_depth_fraction = kDefaultMinValidDepthFraction;  // of the frame's pixels
  double min_mean_intensity = kDefaultMinMeanIntensity;              // 0..1; below = black image
  // Fraction of the keyframe's selected pixels that must land in the frame
  // with valid depth at the finest level.
  double min_overlap = kDefaultMinOverlap;
  // Largest correction of the constant-velocity prediction still inside the
  // convergence basin; beyond it the estimate is not trusted.
  double max_frame_translation = kDefaultMaxFrameTranslation;
  double max_frame_rotation_deg = kDefaultMaxFrameRotationDeg;
  // A frame this long after the last good one (a gap in the data, a camera
  // that stalled) is not aligned to the keyframe: the motion meanwhile is
  // unknown, and an alignment from a guess can converge to a wrong pose that
  // passes every check (7-Scenes with 1.7 s cut out: 0.36 m estimated for a
  // 0.50 m jump). It is lost and relocalised instead.
  double max_gap_s = kDefaultMaxGapS;
  // Largest robust scales of the intensity (0..1) and depth (metres)
  // residuals of a good alignment; real sequences stay well below (7-Scenes at
  // most 0.14 and 0.035, TUM fr3/teddy 0.076 and 0.18), a wrong alignment
  // across a jump does not.
  double max_intensity_sigma = kDefaultMaxIntensitySigma;
  double max_depth_sigma = kDefaultMaxDepthSigma;
  // ... but only when the entropy ratio has also fallen below this: a long
  // keyframe on a scene with fuzzy depth edges (TUM teddy at full resolution)
  // reaches those scales with a sound, only slowly degrading estimate.
  double residual_entropy_ratio = kDefaultResidualEntropyRatio;
  // After this many lost frames in a row a trackable frame starts a new
  // keyframe at the last good pose (the chain of odometry constraints breaks).
  int max_lost_frames = kDefaultMaxLostFrames;
  // A lost but trackable frame is relocalised against every keyframe
  // (relocaliser.hpp), nearest the last good pose first, for at most this
  // long; the search goes on with the next frame where it stopped.
  double relocalise_budget_ms = kDefaultRelocaliseBudgetMs;

  void validate() const;
};

// Loop-closure detection between DVO keyframes (Kerl et al. IROS 2013, as the
// released DVO-SLAM validates constraints), off the per-frame path.
struct LoopClosureParams {
  enum class WhenBehind { kHold, kFewer };  // see when_behind
  static constexpr bool kDefaultEnabled = true;
  static constexpr double kDefaultSearchRadius = 1.0;
  static constexpr int kDefaultExcludePredecessors = 20;
  static constexpr double kDefaultCoarseEntropyRatio = 0.7;
  static constexpr double kDefaultFineEntropyRatio = 0.9;
  static constexpr double kDefaultMinPixelRatio = 0.2;
  static constexpr double kDefaultMaxCrossCheck = 0.05;
  static constexpr int kDefaultMaxCandidates = 0;
  static constexpr int kDefaultQueueCapacity = 128;
  static constexpr int kDefaultCandidatesWhenBehind = 4;
  static constexpr WhenBehind kDefaultWhenBehind = WhenBehind::kHold;
  static constexpr bool kDefaultBothDirections = true;
  static constexpr double kDefaultRefinePhotometricWeight = 0.2;

  bool enabled = kDefaultEnabled;
  // Candidates: earlier keyframes whose camera centre lies within this many
  // metres of the new keyframe's current estimate.
  double search_radius = kDefaultSearchRadius;
  // The new keyframe's last predecessors are never candidates (1: only the one
  // odometry already links, as DVO-SLAM). Loops to recent keyframes share the
  // odometry's errors and the optimiser weighs them as independent: on the
  // 7-Scenes loop (1000 frames) ATE with loop closures / odometry alone is
  // 0.93 excluding 1, 0.81 excluding 5, 0.78 excluding 10, 0.76 excluding 20,
  // 0.87 excluding 40 (loop_closure_bench).
  int exclude_predecessors = kDefaultExcludePredecessors;
  // Thresholds on the ratio ln det(I_loop) / mean ln det(I_odometry), i.e. the
  // paper's entropy ratio with H ~ ln det(covariance): at the coarse stage
  // (coarsest level only) and at the fine stage (all aligner levels), each
  // against odometry constraints aligned on the same levels.
  double coarse_entropy_ratio = kDefaultCoarseEntropyRatio;
  double fine_entropy_ratio = kDefaultFineEntropyRatio;
  // Fraction of the candidate's selected pixels that must constrain the
  // alignment at its finest level (DVO-SLAM's equation-system constraint ratio).
  double min_pixel_ratio = kDefaultMinPixelRatio;
  // The pair aligned the other way round, from the inverse of the accepted
  // result, must land within this many metres of it.
  double max_cross_check_m = kDefaultMaxCrossCheck;
  // The loop's pose is the mean (SE(3) midpoint) of both directions'
  // alignments (the cross check's and the forward one) rather than the
  // forward one alone. Each direction warps only its reference keyframe's
  // selected pixels and carries its own bias (7-Scenes: color not registered
  // to depth); the mean halves what is not shared. The information stays the
  // forward alignment's. loop_closure_bench, ATE with loops / odometry alone:
  // 7-Scenes loop 0.756 -> 0.733 (the information-weighted mean: 0.757);
  // synthetic room 0.475 -> 0.427 (loop edge error median 0.6 -> 0.3 mm),
  // every 3rd frame 0.387 -> 0.393 (sub-millimetre either way); TUM teddy has
  // no loop (ATE 1.41 cm either way).
  bool both_directions = kDefaultBothDirections;
  // An accepted loop's alignments (forward and backward) are refined from
  // their results with the photometric rows weighted by this (1 = no
  // refinement; AlignerParams::photometric_weight); its pose is then taken
  // from the refined pair, its information and acceptance stay the full
  // alignment's. Where color is not registered to depth (7-Scenes) the
  // photometric residual pulls a wide-baseline alignment by the parallax of
  // the misregistration; the geometric term has no such bias. A refinement
  // that moves a direction by more than max_cross_check_m is dropped (the full
  // result is kept). loop_closure_bench, ATE with loops / odometry alone at
  // weights 1 / 0.5 / 0.3 / 0.2 / 0.1 / 0: 7-Scenes loop, 1000 frames, 0.733 /
  // 0.677 / 0.671 / 0.668 / 0.679 / 0.676 (loop edges' median error 2.43 cm /
  // 1.10 deg at 1, 2.04 cm / 0.78 deg at 0.2); its first 700 frames 0.698 ->
  // 0.613 at 0.2, first 850 0.803 -> 0.718; synthetic room (registered color)
  // 0.427 -> 0.435 (0.3 mm either way). Taking the refined information as well
  // was worse (0.740): it discounts intensity evidence that the entropy tests
  // and the optimiser's information_scale count.
  double refine_photometric_weight = kDefaultRefinePhotometricWeight;
  // Candidates checked per keyframe, nearest views first (0 = all).
  int max_candidates = kDefaultMaxCandidates;
  // What the tracker does while other keyframes wait for their checks (the
  // worker is behind: LoopClosureWorker::kBehindWhenWaiting). kHold: it holds
  // its frame acknowledgements back (the frame source waits; every candidate
  // is checked), for a source that can wait (a recording at rate max): the
  // result does not depend on how fast the machine is. kFewer: a check takes
  // at most candidates_when_behind candidates, nearest views first (0 = no
  // such limit), for a live source, which drops frames it cannot send: the
  // worker catches up instead of its queue, and the keyframes it holds,
  // growing. The 3-lap corridor unpaced (tests/longrun/run_corridor.sh) with
  // kFewer checked 6 581 candidates and skipped 12 625: its mesh's CORR
  // median was 1.39 mm against 0.72 mm with every candidate checked.
  WhenBehind when_behind = kDefaultWhenBehind;
  int candidates_when_behind = kDefaultCandidatesWhenBehind;
  // Keyframes waiting for their check; when full the oldest waiting check is
  // dropped (the keyframe stays a candidate for later keyframes).
  int queue_capacity = kDefaultQueueCapacity;

  void validate() const;
};

// How many DVO keyframes stay in memory (keyframe_cache.hpp).
struct KeyframeMemoryParams {
  static constexpr const char* kAutoSpillDir = "auto";
  // 0: all of them (no files; the default of params built in code).
  int keyframes_in_memory = 0;
  // "auto": $TMPDIR (else /tmp)/rekon_tracker_<pid>.spill; else a folder.
  std::string spill_dir = kAutoSpillDir;
  // Freed heap memory kept resident at most (MB) before the loop-closure
  // worker hands its pages back (releaseFreedMemoryBeyond); 0: never.
  double heap_slack_mb = 0.0;

  void validate() const;
};

struct TrackerParams {
  AlignerParams aligner;
  KeyframeParams keyframe;
  LostParams lost;
  LoopClosureParams loop;
  KeyframeMemoryParams memory;

  void validate() const;
};

// Reads the `tracker.*` keys of `config` and validates them.
TrackerParams trackerParamsFromConfig(const Config& config);

}  // namespace rekon::tracker
