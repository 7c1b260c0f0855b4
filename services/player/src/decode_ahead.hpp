#pragma once
// Loads and decodes the frames after the one being sent on worker threads, so
// that PNG inflate and JPEG decoding (4.7 ms a 7-Scenes frame, bench_player.sh) overlap
// the sending and each other instead of setting the replay's pace. Frames are
// taken in order, or with a skip forward (the player with pacing: live behind
// its clock): what was prepared from the taken frame on is kept, what lies
// before it is abandoned without waiting for it (its worker finishes on its
// own, counted in `unused()`, and no new one starts until it has). A request
// for an earlier frame (a rewind for a restarted consumer) abandons all of it.
// A decoding error reaches the caller when it takes that frame, with the same
// message as decoding it there.
#include <chrono>
#include <deque>
#include <future>
#include <utility>
#include <vector>

#include "rekon/common/dataset.hpp"

namespace rekon {

struct LoadedFrame {
  EncodedFrame encoded;
  RgbdFrame frame;
};

class DecodeAhead {
 public:
  // `threads` frames are decoded ahead at most (0: each on take()); frames [0, end).
  DecodeAhead(const TumDataset& dataset, int threads, int64_t end) : dataset_(dataset), threads_(threads), end_(end) {}
  DecodeAhead(const DecodeAhead&) = delete;
  DecodeAhead& operator=(const DecodeAhead&) = delete;
  ~DecodeAhead() {
    abandonBefore(end_);
    for (auto& f : abandoned_) waitQuietly(f);
  }

  LoadedFrame take(int64_t id) {
    abandonBefore(ahead_.empty() || ahead_.front().first > id ? end_ : id);
    reap();
    LoadedFrame loaded;
    if (ahead_.empty()) {
      loaded = load(id);
    } else {
      std::future<LoadedFrame> next = std::move(ahead_.front().second);
      ahead_.pop_front();
      loaded = next.get();  // rethrows its decoding error
    }
    for (int64_t next = ahead_.empty() ? id + 1 : ahead_.back().first + 1;
         static_cast<int>(ahead_.size() + abandoned_.size()) < threads_ && next < end_; ++next) {
      ahead_.emplace_back(next, std::async(std::launch::async, [this, next] { return load(next); }));
    }
    return loaded;
  }

  LoadedFrame load(int64_t id) const {
    const size_t i = static_cast<size_t>(id);
    LoadedFrame l;
    l.encoded = dataset_.loadEncoded(i);
    l.frame = dataset_.decode(i, l.encoded);  // validates the files before anyone sees them
    return l;
  }

  // Frames decoded ahead and never taken (skipped past or rewound over).
  int64_t unused() const { return unused_; }

 private:
  static void waitQuietly(std::future<LoadedFrame>& f) {
    try {
      f.get();
    } catch (...) {  // its error belongs to a frame never taken
    }
  }

  // Abandons the prepared frames before `id`; their workers finish on their own.
  void abandonBefore(int64_t id) {
    while (!ahead_.empty() && ahead_.front().first < id) {
      abandoned_.push_back(std::move(ahead_.front().second));
      ahead_.pop_front();
      ++unused_;
    }
  }

  // Forgets the abandoned workers that have finished.
  void reap() {
    for (auto it = abandoned_.begin(); it != abandoned_.end();) {
      if (it->wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
        waitQuietly(*it);
        it = abandoned_.erase(it);
      } else {
        ++it;
      }
    }
  }

  const TumDataset& dataset_;
  int threads_;
  int64_t end_;
  std::deque<std::pair<int64_t, std::future<LoadedFrame>>> ahead_;
  std::vector<std::future<LoadedFrame>> abandoned_;  // still decoding; they count against `threads_`
  int64_t unused_ = 0;
};

}  // namespace rekon
