#include "rekon/tracker/loop_closure.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <stdexcept>
#include <limits>
#include <numbers>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/common/memory.hpp"
#include "rekon/common/priority.hpp"

namespace rekon::tracker {
namespace {

// The constant of the 6-DoF Gaussian entropy, 0.5 ln((2 pi e)^6).
const double kEntropyConstant = 3.0 * (1.0 + std::log(2.0 * std::numbers::pi));

double viewAngle(const Pose& a, const Pose& b) {
  const Eigen::Vector3d za = a.linear().col(2), zb = b.linear().col(2);
  return std::acos(std::clamp(za.dot(zb), -1.0, 1.0));
}

// The parameters, checked before anything is built from them.
const TrackerParams& validated(const TrackerParams& params) {
  params.validate();
  return params;
}

}  // namespace

double logDetOfEntropy(double entropy) { return 2.0 * (kEntropyConstant - entropy); }

bool informationPasses(double log_det, double reference, double threshold) {
  return log_det - reference >= -(1.0 - threshold) * std::abs(reference);
}

Pose bothDirections(const AlignResult& forward, const AlignResult& backward) {
  // The midpoint on SE(3) of the two estimates of the new keyframe in the
  // candidate. Equal weights, not the information-weighted mean: on the
  // 7-Scenes loop the weighted mean left the ATE ratio where the forward
  // alignment alone has it (0.757 vs 0.756), the midpoint lowered it to 0.733.
  const Vector6d delta = logSe3(forward.pose.inverse() * backward.pose.inverse());
  return orthonormalised(forward.pose * expSe3(0.5 * delta));
}

LoopClosureDetector::LoopClosureDetector(const TrackerParams& params, std::shared_ptr<KeyframeCache> cache)
    : params_(validated(params)), cache_(cache ? std::move(cache) : std::make_shared<KeyframeCache>(params)),
      aligners_(makeAligners()) {}

LoopClosureDetector::Aligners LoopClosureDetector::makeAligners() const {
  Aligners a{DenseAligner(params_.aligner), std::nullopt};
  // Without the geometric term there is nothing to refine towards.
  if (params_.loop.refine_photometric_weight < 1.0 && params_.aligner.use_depth) {
    AlignerParams refining = params_.aligner;
    refining.photometric_weight = params_.loop.refine_photometric_weight;
    a.refiner.emplace(refining);
  }
  return a;
}

std::pair<AlignResult, AlignResult> LoopClosureDetector::refine(const Keyframe& reference, const Keyframe& current,
                                                                const AlignResult& fine, const AlignResult& back,
                                                                Aligners& a) const {
  if (!a.refiner) return {fine, back};
  const double limit = params_.loop.max_cross_check_m;
  auto refined = [&](const KeyframeReference& from, const RgbdPyramid& to, const AlignResult& full) {
    const AlignResult r = a.refiner->align(from, to, full.pose);
    return r.valid && translationDistance(r.pose, full.pose) <= limit ? r : full;
  };
  return {refined(reference.reference, current.pyramid, fine), refined(current.reference, reference.pyramid, back)};
}

void LoopClosureDetector::addKeyframe(std::shared_ptr<const Keyframe> keyframe,
                                      const std::optional<OdometryConstraint>& incoming) {
  addIndexed(keyframe->id, keyframe->pose_world, incoming);
  cache_->add(std::move(keyframe));
}

void LoopClosureDetector::addIndexed(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming) {
  if (incoming && std::isfinite(incoming->entropy)) {
    fine_sum_ += logDetOfEntropy(incoming->entropy);
    ++fine_count_;
  }
  Entry& e = entries_[id];
  e.pose_world = pose_world;
  e.incoming = incoming;
  e.incoming_coarse_log_det.reset();
}

std::shared_ptr<const Keyframe> LoopClosureDetector::keyframe(int64_t id) const {
  auto kf = cache_->get(id);
  if (!kf) throw Error("loop closure: keyframe " + std::to_string(id) + " is not in the keyframe cache");
  return kf;
}

void LoopClosureDetector::updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses) {
  std::lock_guard<std::mutex> lock(graph_mutex_);
  if (version <= graph_version_) return;
  graph_version_ = version;
  graph_ = std::move(poses);
}

int64_t LoopClosureDetector::graphVersion() const {
  std::lock_guard<std::mutex> lock(graph_mutex_);
  return graph_version_;
}

Pose LoopClosureDetector::estimate(int64_t keyframe_id) const {
  const auto it = entries_.find(keyframe_id);
  if (it == entries_.end()) return Pose::Identity();
  const Pose& odometry = it->second.pose_world;
  std::lock_guard<std::mutex> lock(graph_mutex_);
  if (const auto g = graph_.find(keyframe_id); g != graph_.end()) return g->second;
  // Keyframes newer than the graph: their odometry relative to the newest
  // earlier keyframe the graph has, on top of that keyframe's graph pose.
  for (auto a = std::make_reverse_iterator(it); a != entries_.rend(); ++a) {
    if (const auto g = graph_.find(a->first); g != graph_.end())
      return movedWithGraph(g->second, a->second.pose_world, odometry);
  }
  return odometry;
}

std::vector<int64_t> LoopClosureDetector::candidates(int64_t keyframe_id) const {
  std::vector<std::pair<double, int64_t>> ranked;
  if (!entries_.count(keyframe_id)) return {};
  const Pose pose = estimate(keyframe_id);
  const double radius = params_.loop.search_radius;
  for (const auto& [id, entry] : entries_) {
    if (id >= keyframe_id - params_.loop.exclude_predecessors) continue;  // predecessors, itself, later ones
    const Pose other = estimate(id);
    const double d = (other.translation() - pose.translation()).norm();
    if (d > radius) continue;
    // Nearest views first: centre distance plus one search radius per 90
    // degrees between the optical axes.
    ranked.emplace_back(d + radius * viewAngle(pose, other) / (0.5 * std::numbers::pi), id);
  }
  std::sort(ranked.begin(), ranked.end());
  std::vector<int64_t> ids;
  for (const auto& r : ranked) ids.push_back(r.second);
  return ids;
}

std::optional<double> LoopClosureDetector::incomingLogDet(int64_t id, Entry& e, bool coarse) {
  if (!e.incoming || !std::isfinite(e.incoming->entropy)) return std::nullopt;
  if (!coarse) return logDetOfEntropy(e.incoming->entropy);
  if (!e.incoming_coarse_log_det) {
    // The tracker aligned this constraint on all levels; the coarse stage
    // compares with the same constraint aligned on the coarsest level only.
    const auto from = entries_.find(e.incoming->from_id);
    if (from == entries_.end()) return std::nullopt;
    const int coarsest = params_.aligner.coarsest_level;
    const AlignResult r = aligners_.aligner.align(keyframe(from->first)->reference, keyframe(id)->pyramid,
                                                  e.incoming->relative, coarsest, coarsest);
    if (!r.valid) return std::nullopt;
    e.incoming_coarse_log_det = logDetOfEntropy(r.entropy);
    coarse_sum_ += *e.incoming_coarse_log_det;
    ++coarse_count_;
  }
  return e.incoming_coarse_log_det;
}

std::optional<double> LoopClosureDetector::odometryLogDet(int64_t a, int64_t b, bool coarse) {
  double sum = 0.0;
  int n = 0;
  auto add = [&](int64_t id) {
    const auto it = entries_.find(id);
    if (it == entries_.end()) return;
    if (const auto v = incomingLogDet(id, it->second, coarse)) {
      sum += *v;
      ++n;
    }
  };
  add(a);
  if (const auto next = entries_.find(a + 1); next != entries_.end() && next->second.incoming &&
                                              next->second.incoming->from_id == a)
    add(a + 1);
  add(b);
  if (n > 0) return sum / n;
  const double total = coarse ? coarse_sum_ : fine_sum_;
  const int64_t count = coarse ? coarse_count_ : fine_count_;
  if (count == 0) return std::nullopt;
  return total / static_cast<double>(count);
}


std::vector<int64_t> LoopClosureDetector::ids() const {
  std::vector<int64_t> out;
  for (const auto& e : entries_) out.push_back(e.first);
  return out;
}

bool LoopClosureDetector::odometryLinked(int64_t a, int64_t b) const {
  const auto from = [&](int64_t to, int64_t from_id) {
    const auto it = entries_.find(to);
    return it != entries_.end() && it->second.incoming && it->second.incoming->from_id == from_id;
  };
  return from(a, b) || from(b, a);
}

CandidateCheck LoopClosureDetector::check(int64_t candidate_id, int64_t keyframe_id) {
  const auto cur = entries_.find(keyframe_id);
  if (cur == entries_.end()) {
    CandidateCheck out;
    out.candidate_id = candidate_id;
    out.keyframe_id = keyframe_id;
    out.reason = "unknown keyframe";
    return out;
  }
  const Pose relative = orthonormalised(estimate(candidate_id).inverse() * estimate(keyframe_id));
  return check(candidate_id, *keyframe(keyframe_id), {Pose::Identity(), relative});
}

std::vector<Pose> LoopClosureDetector::odometryNeighbours(int64_t id) const {
  std::vector<Pose> out;
  const auto it = entries_.find(id);
  if (it == entries_.end()) return out;
  if (const auto& in = it->second.incoming; in && entries_.count(in->from_id)) out.push_back(in->relative.inverse());
  if (const auto next = entries_.find(id + 1);
      next != entries_.end() && next->second.incoming && next->second.incoming->from_id == id)
    out.push_back(next->second.incoming->relative);
  return out;
}

CandidateCheck LoopClosureDetector::check(int64_t candidate_id, const Keyframe& current,
                                          const std::vector<Pose>& guesses) {
  return align(prepare(candidate_id, current.id), current, guesses, aligners_);
}

LoopClosureDetector::Prepared LoopClosureDetector::prepare(int64_t candidate_id, int64_t current_id) {
  Prepared p;
  p.candidate_id = candidate_id;
  p.known = entries_.count(candidate_id) > 0;
  if (!p.known) return p;
  p.coarse_ref = odometryLogDet(candidate_id, current_id, true);
  p.fine_ref = odometryLogDet(candidate_id, current_id, false);
  if (p.coarse_ref && p.fine_ref) p.reference = keyframe(candidate_id);
  return p;
}

CandidateCheck LoopClosureDetector::align(const Prepared& p, const Keyframe& current, const std::vector<Pose>& guesses,
                                          Aligners& a) const {
  CandidateCheck out;
  out.candidate_id = p.candidate_id;
  out.keyframe_id = current.id;
  if (!p.known) {
    out.reason = "unknown keyframe";
    return out;
  }
  if (!p.reference) {
    out.reason = "no odometry constraint to compare with";
    return out;
  }
  const double coarse_ref = *p.coarse_ref, fine_ref = *p.fine_ref;
  const int64_t candidate_id = p.candidate_id;
  const Keyframe& reference = *p.reference;
  const int coarsest = params_.aligner.coarsest_level;
  const LoopClosureParams& lp = params_.loop;
  out.reason = "coarse stage";
  double best_log_det = -std::numeric_limits<double>::infinity();
  for (const Pose& guess : guesses) {
    const AlignResult coarse = a.aligner.align(reference.reference, current.pyramid, guess, coarsest, coarsest);
    if (!coarse.valid) continue;
    const double coarse_log_det = logDetOfEntropy(coarse.entropy);
    const double coarse_ratio = coarse_log_det / coarse_ref;
    out.best_coarse_ratio = std::max(out.best_coarse_ratio, coarse_ratio);
    if (!informationPasses(coarse_log_det, coarse_ref, lp.coarse_entropy_ratio) ||
        coarse.valid_pixels < lp.min_pixel_ratio * coarse.selected_pixels)
      continue;
    const AlignResult fine = a.aligner.align(reference.reference, current.pyramid, coarse.pose);
    if (!fine.valid) {
      out.reason = "fine alignment failed";
      continue;
    }
    const double fine_log_det = logDetOfEntropy(fine.entropy);
    const double fine_ratio = fine_log_det / fine_ref;
    out.best_fine_ratio = std::max(out.best_fine_ratio, fine_ratio);
    if (!informationPasses(fine_log_det, fine_ref, lp.fine_entropy_ratio)) {
      out.reason = "fine entropy ratio";
      continue;
    }
    if (fine.valid_pixels < lp.min_pixel_ratio * fine.selected_pixels) {
      out.reason = "too few constraining pixels";
      continue;
    }
    // Of the two initial guesses keep the better-determined result (DVO-SLAM's keepBest).
    if (fine_log_det <= best_log_det) continue;
    // DVO-SLAM's cross validation: the same pair aligned the other way round
    // from the inverse result must come back to it. A true minimum of the
    // joint residual does; a wrong one reached from a far guess mostly does not.
    const AlignResult back = a.aligner.align(current.reference, reference.pyramid, fine.pose.inverse());
    const double cross = back.valid ? (back.pose * fine.pose).translation().norm() : std::numeric_limits<double>::infinity();
    if (cross > lp.max_cross_check_m) {
      out.reason = "cross check";
      continue;
    }
    best_log_det = fine_log_det;
    const auto [forward, backward] = refine(reference, current, fine, back, a);
    LoopConstraint c;
    c.from_id = candidate_id;
    c.to_id = current.id;
    c.relative = lp.both_directions ? bothDirections(forward, backward) : forward.pose;
    c.information = fine.information;
    c.coarse_ratio = coarse_ratio;
    c.fine_ratio = fine_ratio;
    c.valid_pixels = fine.valid_pixels;
    c.cross_check_m = cross;
    c.intensity_sigma = fine.intensity_sigma;
    c.depth_sigma = fine.depth_sigma;
    out.constraint = c;
    out.accepted = true;
    out.reason = "";
  }
  return out;
}

std::vector<CandidateCheck> LoopClosureDetector::alignAll(const std::vector<Prepared>& prepared, const Keyframe& current,
                                                          const std::vector<std::vector<Pose>>& guesses) {
  std::vector<CandidateCheck> out(prepared.size());
  const size_t threads = std::min(prepared.size(), static_cast<size_t>(threads_.load()));
  while (helpers_.size() + 1 < threads) helpers_.push_back(std::make_unique<Aligners>(makeAligners()));
  std::atomic<size_t> next{0};
  std::vector<std::exception_ptr> errors(std::max<size_t>(threads, 1));
  auto work = [&](Aligners& a, std::exception_ptr& error) {
    try {
      for (size_t i = next++; i < prepared.size(); i = next++) out[i] = align(prepared[i], current, guesses[i], a);
    } catch (...) {
      error = std::current_exception();
      next = prepared.size();  // the others stop too
    }
  };
  std::vector<std::thread> pool;
  for (size_t t = 1; t < threads; ++t) pool.emplace_back(work, std::ref(*helpers_[t - 1]), std::ref(errors[t]));
  work(aligners_, errors[0]);
  for (std::thread& t : pool) t.join();
  for (const std::exception_ptr& e : errors)
    if (e) std::rethrow_exception(e);
  return out;
}

std::vector<LoopConstraint> LoopClosureDetector::detect(int64_t keyframe_id, LoopClosureStats& stats, bool behind) {
  std::vector<LoopConstraint> accepted;
  std::vector<int64_t> ids = candidates(keyframe_id);
  const auto limit = [&](int most) {
    if (most <= 0 || ids.size() <= static_cast<size_t>(most)) return;
    stats.candidates_skipped += static_cast<int64_t>(ids.size()) - most;
    ids.resize(static_cast<size_t>(most));
  };
  limit(params_.loop.max_candidates);
  if (behind) {
    ++stats.checks_behind;
    limit(params_.loop.candidates_when_behind);
  }
  ++stats.keyframes_checked;
  if (ids.empty()) return accepted;
  // The database is read here, in candidate order; the alignments may then run side by side.
  std::vector<Prepared> prepared;
  std::vector<std::vector<Pose>> guesses;
  for (const int64_t id : ids) {
    prepared.push_back(prepare(id, keyframe_id));
    guesses.push_back({Pose::Identity(), orthonormalised(estimate(id).inverse() * estimate(keyframe_id))});
  }
  for (const CandidateCheck& c : alignAll(prepared, *keyframe(keyframe_id), guesses)) {
    ++stats.candidates;
    if (c.accepted) {
      ++stats.accepted;
      spdlog::debug("loop closure {} -> {} accepted (ln det ratios coarse {:.3f}, fine {:.3f})", c.candidate_id,
                    keyframe_id, c.constraint->coarse_ratio, c.constraint->fine_ratio);
      accepted.push_back(*c.constraint);
    } else {
      ++stats.rejected;
      spdlog::debug("loop closure {} -> {} rejected: {} (ln det ratios coarse {:.3f}, fine {:.3f})", c.candidate_id,
                    keyframe_id, c.reason, c.best_coarse_ratio, c.best_fine_ratio);
    }
  }
  return accepted;
}

LoopClosureWorker::LoopClosureWorker(const TrackerParams& params, AcceptFn on_accept, bool start,
                                     std::shared_ptr<KeyframeCache> cache)
    : detector_(params, std::move(cache)),
      on_accept_(std::move(on_accept)),
      heap_slack_bytes_(static_cast<size_t>(params.memory.heap_slack_mb * 1024 * 1024)) {
  thread_ = std::thread([this] { run(); });
  if (start) this->start();
}

LoopClosureWorker::~LoopClosureWorker() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
    started_ = true;
  }
  wake_.notify_all();
  thread_.join();
}

void LoopClosureWorker::start() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    started_ = true;
  }
  wake_.notify_all();
}

void LoopClosureWorker::submit(std::shared_ptr<const Keyframe> keyframe,
                               const std::optional<OdometryConstraint>& incoming) {
  if (!detector_.params().enabled) return;  // nothing will ever be checked: keep no keyframes
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (waiting_checks_ >= detector_.params().queue_capacity) dropOldestCheck();
    queue_.push_back(Job{std::move(keyframe), incoming, Kind::kCheck});
    ++waiting_checks_;
  }
  wake_.notify_one();
}

// The oldest check goes (the newest keyframes are where the camera is now);
// its keyframe stays queued as a candidate for later keyframes' checks.
void LoopClosureWorker::dropOldestCheck() {
  const auto job = std::find_if(queue_.begin(), queue_.end(), [](const Job& j) { return j.kind == Kind::kCheck; });
  if (job == queue_.end()) return;
  if (waiting_candidates_ >= detector_.params().queue_capacity) dropOldestCandidate();
  job->kind = Kind::kCandidate;
  --waiting_checks_;
  ++waiting_candidates_;
  ++stats_.checks_dropped;
  spdlog::warn("loop-closure queue full ({} keyframes): dropped the check of keyframe {} ({} dropped so far)",
               detector_.params().queue_capacity, job->keyframe->id, stats_.checks_dropped);
}

// Only while the worker is stalled: the oldest waiting candidate goes, so that
// the newer ones (nearer the keyframes still to be checked) stay.
void LoopClosureWorker::dropOldestCandidate() {
  const auto job = std::find_if(queue_.begin(), queue_.end(), [](const Job& j) { return j.kind == Kind::kCandidate; });
  spdlog::warn("loop-closure worker stalled ({} keyframes wait): keyframe {} will not be a loop candidate ({} left out so far)",
               queue_.size(), job->keyframe->id, stats_.candidates_dropped + 1);
  queue_.erase(job);
  --waiting_candidates_;
  ++stats_.candidates_dropped;
}

void LoopClosureWorker::addStored(std::shared_ptr<const Keyframe> keyframe,
                                  const std::optional<OdometryConstraint>& incoming) {
  if (!detector_.params().enabled) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    queue_.push_back(Job{std::move(keyframe), incoming, Kind::kStored});
  }
  wake_.notify_one();
}

void LoopClosureWorker::addIndexed(int64_t id, const Pose& pose_world, const std::optional<OdometryConstraint>& incoming) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (started_) throw std::logic_error("LoopClosureWorker::addIndexed after start()");
  if (detector_.params().enabled) detector_.addIndexed(id, pose_world, incoming);
}

void LoopClosureWorker::updateGraph(int64_t version, std::unordered_map<int64_t, Pose> poses) {
  detector_.updateGraph(version, std::move(poses));
}

bool LoopClosureWorker::waitUntilDrained(int timeout_ms) {
  std::unique_lock<std::mutex> lock(mutex_);
  const auto done = [&] { return queue_.empty() && !busy_; };
  if (!started_) return done();
  return drained_.wait_for(lock, std::chrono::milliseconds(timeout_ms), done);
}

bool LoopClosureWorker::behind() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return waiting_checks_ >= kBehindWhenWaiting;
}

LoopClosureStats LoopClosureWorker::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

std::vector<int64_t> LoopClosureWorker::checkedKeyframes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return checked_;
}

void LoopClosureWorker::run() {
  // Below the tracking thread's priority (Linux: a thread id takes a nice
  // value of its own), so that on a busy machine checks yield to tracking.
  if (!setThisThreadsNice(10))
    spdlog::debug("loop-closure worker keeps the default priority");
  for (;;) {
    Job job;
    bool fewer = false;  // kBehindWhenWaiting or more checks wait behind this one, and when_behind is kFewer
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [&] { return stop_ || (started_ && !queue_.empty()); });
      if (stop_) return;
      job = std::move(queue_.front());
      queue_.pop_front();
      waiting_checks_ -= job.kind == Kind::kCheck;
      fewer = waiting_checks_ >= kBehindWhenWaiting &&
              detector_.params().when_behind == LoopClosureParams::WhenBehind::kFewer;
      waiting_candidates_ -= job.kind == Kind::kCandidate;
      busy_ = true;
    }
    const auto t0 = std::chrono::steady_clock::now();
    LoopClosureStats local;
    try {  // an exception must not end the tracker (std::terminate): this keyframe's loops are lost, one line says why
      detector_.addKeyframe(job.keyframe, job.incoming);
      std::vector<LoopConstraint> accepted;
      if (job.kind == Kind::kCheck) accepted = detector_.detect(job.keyframe->id, local, fewer);
      for (const LoopConstraint& c : accepted) on_accept_(c);
    } catch (...) {
      spdlog::error("loop closure check of keyframe {} failed, no loop edges from it: {}", job.keyframe->id,
                    currentExceptionLine());
    }
    // What the check read back and the cache evicted is freed by now (unless
    // the tracking thread still holds it): past the slack its pages go back,
    // so that the tracker's memory follows what it keeps.
    const int64_t id = job.keyframe->id, frame_id = job.keyframe->frame_id;
    job.keyframe.reset();
    if (on_settled_ && job.kind != Kind::kStored) on_settled_(id);
    const bool trimmed = heap_slack_bytes_ > 0 && releaseFreedMemoryBeyond(heap_slack_bytes_);
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    if (job.kind == Kind::kCheck && on_checked_) on_checked_(id, frame_id, local, ms);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (job.kind == Kind::kCheck) {
        checked_.push_back(id);
        stats_.keyframes_checked += local.keyframes_checked;
        stats_.candidates += local.candidates;
        stats_.accepted += local.accepted;
        stats_.rejected += local.rejected;
        stats_.candidates_skipped += local.candidates_skipped;
        stats_.checks_behind += local.checks_behind;
        stats_.check_ms += ms;
      }
      stats_.heap_trims += trimmed;
      busy_ = false;
      if (queue_.empty()) drained_.notify_all();
    }
  }
}

}  // namespace rekon::tracker
