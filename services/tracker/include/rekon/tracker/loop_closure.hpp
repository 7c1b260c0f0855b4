#pragma once
// Loop-closure detection between DVO keyframes, as the released DVO-SLAM
// validates constraints (Kerl, Sturm, Cremers, IROS 2013): every earlier
// keyframe whose camera centre lies within a sphere around the new keyframe's
// current estimate is a candidate; each is aligned to the new keyframe from
// identity and from the current relative pose estimate, first on the coarsest
// level only, then coarse to fine from the coarse result; a constraint is
// accepted when, at both stages, ln det of its information is at least the
// threshold times the mean ln det of the odometry constraints around the two
// keyframes aligned on the same levels (the paper's entropy ratio with
// H ~ ln det(covariance)), and enough of the candidate's pixels constrain it.
#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>
#include <vector>

#include "rekon/tracker/dense_aligner.hpp"
#include "rekon/tracker/keyframe_cache.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/tracker.hpp"

namespace rekon::tracker {

// ln det(information) of a 6-DoF Gaussian from its differential entropy
// (entropyOfInformation): the quantity DVO-SLAM's entropy ratio divides.
double logDetOfEntropy(double entropy);

// log_det / reference >= threshold, written so that it stays meaningful for a
// non-positive reference: an alignment may carry at most (1 - threshold) of
// the reference's magnitude less information (ln det) than the odometry it is
// compared with.
bool informationPasses(double log_det, double reference, double threshold);

// The mean (SE(3) midpoint) of a loop pose aligned both ways: `forward` is
// the new keyframe aligned to the candidate, `backward` the candidate aligned
// to the new keyframe (both valid).
Pose bothDirections(const AlignResult& forward, const AlignResult& backward);

// A validated loop closure: pose of keyframe `to_id` (the new one) in the
// frame of `from_id` (the earlier candidate), right-perturbation information
// in (v, w) order, as OdometryConstraint.
struct LoopConstraint {
  int64_t from_id = 0;
  int64_t to_id = 0;
  Pose relative = Pose::Identity();
  Matrix6d information = Matrix6d::Zero();
  double coarse_ratio = 0.0;  // ln det ratios against the odometry at each stage
  double fine_ratio = 0.0;
  int valid_pixels = 0;
  // Disagreement of the alignment run the other way round (the candidate
  // aligned to the new keyframe from the inverse result): translation, metres.
  double cross_check_m = 0.0;
  double intensity_sigma = 0.0;  // robust residual scales of the fine alignment
  double depth_sigma = 0.0;
};

// The outcome of checking one candidate.
struct CandidateCheck {
  int64_t candidate_id = 0;
  int64_t keyframe_id = 0;
  bool accepted = false;
  std::optional<LoopConstraint> constraint;  // set when accepted
  double best_coarse_ratio = 0.0;            // over both initial guesses (0 when no alignment was valid)
  double best_fine_ratio = 0.0;
  const char* reason = "";  // why it was rejected
};

struct LoopClosureStats {
  int64_t keyframes_checked = 0;
  int64_t candidates = 0;  // candidates aligned
  int64_t accepted = 0;
  int64_t rejected = 0;
  int64_t candidates_skipped = 0;  // beyond max_candidates, or candidates_when_behind
  int64_t checks_behind = 0;       // checks made while others waited (candidates_when_behind applied)
  int64_t checks_dropped = 0;      // keyframes whose check the full queue dropped
  int64_t candidates_dropped = 0;  // keyframes whose check was dropped and that the full queue then left out as candidates
  double check_ms = 0.0;           // wall time of all checks (with their memory hand-backs)
  int64_t heap_trims = 0;          // freed memory handed back after a check (KeyframeMemoryParams::heap_slack_mb)
};

// The synchronous core: a database of keyframes with their odometry
// constraints and pose estimates. Not thread-safe except updateGraph(),
// which another thread may call at any time.
class LoopClosureDetector {
 public:
  // `cache` holds the keyframes' images (shared with another detector);
  // null: one of its own, sized by params.memory.
  explicit LoopClosureDetector(const TrackerParams& params, std::shared_ptr<KeyframeCache> cache = nullptr);

  // Adds a keyframe as a future candidate; `incoming` links it to its
  // predecessor (absent for the first keyframe and after a tracking reset).
  void addKeyframe(std::shared_ptr<const Keyframe> keyframe, const std::optional<OdometryConstraint>& incoming);
  // The same for a keyframe the cache already holds or indexes (a restarted
  // tracker's archive: KeyframeCache::addArchived), by id and odometry pose.
  void addIndexed(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming);

  // The optimiser's keyframe poses; an update older than the newest seen is ignored.
  void updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses);
  int64_t graphVersion() const;

  // World pose of an added keyframe: the newest graph update's pose when it
  // has one, else its odometry pose moved with the nearest earlier keyframe
  // the graph has (the odometry pose when the graph has none).
  Pose estimate(int64_t keyframe_id) const;

  // Candidate ids for an added keyframe, nearest views first (all of them;
  // the caller applies max_candidates).
  std::vector<int64_t> candidates(int64_t keyframe_id) const;

  // Aligns keyframe `keyframe_id` to the earlier `candidate_id` and validates the result.
  CandidateCheck check(int64_t candidate_id, int64_t keyframe_id);
  // The same for a keyframe that need not be in the database (a frame being
  // relocalised, relocaliser.hpp), aligned from each of `guesses` (poses of
  // `current` in the candidate).
  CandidateCheck check(int64_t candidate_id, const Keyframe& current, const std::vector<Pose>& guesses);
  // The poses, in keyframe `id`'s frame, of the keyframes odometry links it
  // to (its predecessor and successor, when linked).
  std::vector<Pose> odometryNeighbours(int64_t id) const;
  // Ids of the keyframes added, ascending.
  std::vector<int64_t> ids() const;
  // Whether an odometry constraint links keyframes `a` and `b` (either way).
  bool odometryLinked(int64_t a, int64_t b) const;
  // An added keyframe with its images (rekon::Error when the cache lost it).
  std::shared_ptr<const Keyframe> keyframe(int64_t id) const;

  // candidates() then check() for each (up to max_candidates, and with
  // `behind` up to candidates_when_behind); accumulates into `stats`.
  std::vector<LoopConstraint> detect(int64_t keyframe_id, LoopClosureStats& stats, bool behind = false);
  // Threads that detect()'s alignments run on from now on (1, the default:
  // the calling thread only). The outcome does not depend on it: each
  // candidate is checked on its own, the results taken in candidate order.
  void setThreads(int threads) { threads_ = std::max(1, threads); }

  const LoopClosureParams& params() const { return params_.loop; }
  KeyframeCacheStats keyframeCacheStats() const { return cache_->stats(); }

 private:
  struct Entry {
    Pose pose_world = Pose::Identity();  // the keyframe's odometry pose; its images are in cache_
    std::optional<OdometryConstraint> incoming;
    std::optional<double> incoming_coarse_log_det;  // computed when first needed
  };
  // Mean ln det of the odometry constraints into and out of `a` and into `b`
  // (the global mean when none), at the coarse stage or the fine stage.
  std::optional<double> odometryLogDet(int64_t a, int64_t b, bool coarse);
  std::optional<double> incomingLogDet(int64_t id, Entry& e, bool coarse);

  // A check's aligners: their buffers are its working state, so each thread
  // of detect() has its own.
  struct Aligners {
    DenseAligner aligner;
    std::optional<DenseAligner> refiner;  // absent when refinement is off
  };
  Aligners makeAligners() const;
  // What checking a candidate reads of the database, read before its
  // alignments (on the calling thread: it fills caches), so that those can
  // run on any thread.
  struct Prepared {
    int64_t candidate_id = -1;
    bool known = false;                         // the candidate is in the database
    std::optional<double> coarse_ref, fine_ref;  // odometryLogDet of the pair
    std::shared_ptr<const Keyframe> reference;  // the candidate, when both are known
  };
  Prepared prepare(int64_t candidate_id, int64_t current_id);
  CandidateCheck align(const Prepared& p, const Keyframe& current, const std::vector<Pose>& guesses, Aligners& a) const;
  // align() for each, on up to threads_ threads; results in the order given.
  std::vector<CandidateCheck> alignAll(const std::vector<Prepared>& prepared, const Keyframe& current,
                                       const std::vector<std::vector<Pose>>& guesses);
  // The accepted pair's forward (`fine`) and backward alignments refined by
  // a.refiner (LoopClosureParams::refine_photometric_weight); each falls back
  // to its full result when its refinement fails or strays.
  std::pair<AlignResult, AlignResult> refine(const Keyframe& reference, const Keyframe& current,
                                             const AlignResult& fine, const AlignResult& back, Aligners& a) const;

  TrackerParams params_;
  std::shared_ptr<KeyframeCache> cache_;
  Aligners aligners_;                                // the calling thread's
  std::vector<std::unique_ptr<Aligners>> helpers_;  // detect()'s other threads'
  std::atomic<int> threads_{1};
  std::map<int64_t, Entry> entries_;
  double fine_sum_ = 0.0, coarse_sum_ = 0.0;
  int64_t fine_count_ = 0, coarse_count_ = 0;
  mutable std::mutex graph_mutex_;
  int64_t graph_version_ = -1;
  std::unordered_map<int64_t, Pose> graph_;
};

// LoopClosureDetector on a worker thread behind a bounded queue: submit()
// never blocks on a check, so tracking is never delayed; accepted
// constraints go to `on_accept` on the worker thread.
class LoopClosureWorker {
 public:
  using AcceptFn = std::function<void(const LoopConstraint&)>;
  // The worker is behind (LoopClosureParams::when_behind applies) when at
  // least this many checks wait: about 4 s of keyframes on the corridor at
  // 30 Hz, a lag that lasts rather than a burst of keyframes.
  static constexpr int kBehindWhenWaiting = 8;

  // `start` false: the worker waits for start() (tests fill the queue first).
  LoopClosureWorker(const TrackerParams& params, AcceptFn on_accept, bool start = true,
                    std::shared_ptr<KeyframeCache> cache = nullptr);
  ~LoopClosureWorker();
  LoopClosureWorker(const LoopClosureWorker&) = delete;
  LoopClosureWorker& operator=(const LoopClosureWorker&) = delete;

  void start();
  // Called on the worker thread with a new keyframe's id once its check is
  // settled: run (its accepted constraints already handed to `on_accept`) or
  // dropped by a full queue (it was then only added as a candidate). Set
  // before start().
  void onSettled(std::function<void(int64_t)> settled) { on_settled_ = std::move(settled); }
  // Called on the worker thread after a new keyframe's check ran, with the
  // keyframe's id and frame id, what the check found (its counts alone) and
  // its wall time in ms, the memory hand-back after it included. Set before start().
  using CheckedFn = std::function<void(int64_t keyframe_id, int64_t frame_id, const LoopClosureStats& check, double ms)>;
  void onChecked(CheckedFn checked) { on_checked_ = std::move(checked); }
  // Queues a new keyframe's check; when queue_capacity checks already wait,
  // the oldest waiting one is dropped with a warning (its keyframe still waits,
  // to be added as a candidate). When queue_capacity such keyframes wait too
  // (the worker is stalled), the oldest of them is dropped as well, warned and
  // counted: a queue never holds more than 2 x queue_capacity new keyframes.
  void submit(std::shared_ptr<const Keyframe> keyframe, const std::optional<OdometryConstraint>& incoming);
  // A keyframe of an earlier run (a continued session): a candidate, never checked itself.
  void addStored(std::shared_ptr<const Keyframe> keyframe, const std::optional<OdometryConstraint>& incoming);
  // A restarted tracker's earlier keyframe, indexed in the shared cache
  // (LoopClosureDetector::addIndexed): a candidate, never checked itself.
  // Before start() only (a worker made with start false).
  void addIndexed(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming);
  void updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses);
  // Waits until every queued keyframe has been handled, at most `timeout_ms`;
  // true when drained (false at once when not started and not empty).
  bool waitUntilDrained(int timeout_ms);
  LoopClosureStats stats() const;
  // kBehindWhenWaiting or more checks wait.
  bool behind() const;
  // The DVO keyframes' tiers (memory, disk).
  KeyframeCacheStats keyframeCacheStats() const { return detector_.keyframeCacheStats(); }
  // Ids of the keyframes whose check ran, in order.
  std::vector<int64_t> checkedKeyframes() const;
  // Checks from now on use this many threads (LoopClosureDetector::setThreads):
  // the tracker's cores once the stream has ended and tracking is idle.
  void useThreads(int threads) { detector_.setThreads(threads); }

 private:
  // kCheck: a new keyframe, added and checked; kCandidate: a new keyframe
  // whose check was dropped, only added; kStored: from an earlier run, only
  // added (never dropped: a session's keyframes are finite and wanted).
  enum class Kind { kCheck, kCandidate, kStored };
  struct Job {
    std::shared_ptr<const Keyframe> keyframe;
    std::optional<OdometryConstraint> incoming;
    Kind kind = Kind::kCheck;
  };
  void run();
  // Under mutex_: room in the full queue for one more new keyframe.
  void dropOldestCheck();
  void dropOldestCandidate();

  LoopClosureDetector detector_;
  AcceptFn on_accept_;
  std::function<void(int64_t)> on_settled_;
  CheckedFn on_checked_;
  const size_t heap_slack_bytes_;  // 0: never hand freed memory back
  mutable std::mutex mutex_;
  std::condition_variable wake_, drained_;
  std::deque<Job> queue_;
  int waiting_checks_ = 0, waiting_candidates_ = 0;
  bool busy_ = false, stop_ = false, started_ = false;
  LoopClosureStats stats_;
  std::vector<int64_t> checked_;
  std::thread thread_;
};

}  // namespace rekon::tracker
