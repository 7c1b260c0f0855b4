#pragma once
// Loads and decodes the frames after the one being sent on worker threads, so
// that PNG inflate and JPEG decoding (4.7 ms a 7-Scenes frame, bench_player.sh) overlap
// the sending and each other instead of setting the replay's pace. Frames are
// taken in order; a request for any other frame (a rewind for a restarted
// consumer) drops what was prepared. A decoding error reaches the caller when
// it takes that frame, with the same message as decoding it there.
#include <deque>
#include <future>
#include <utility>

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
  ~DecodeAhead() { drop(); }

  LoadedFrame take(int64_t id) {
    if (ahead_.empty() || ahead_.front().first != id) drop();
    LoadedFrame loaded;
    if (ahead_.empty()) {
      loaded = load(id);
    } else {
      std::future<LoadedFrame> next = std::move(ahead_.front().second);
      ahead_.pop_front();
      loaded = next.get();  // rethrows its decoding error
    }
    for (int64_t next = ahead_.empty() ? id + 1 : ahead_.back().first + 1;
         static_cast<int>(ahead_.size()) < threads_ && next < end_; ++next) {
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

 private:
  // Waits for what is being decoded (its errors belong to frames never taken).
  void drop() {
    for (auto& [id, f] : ahead_) {
      try {
        f.get();
      } catch (...) {
      }
    }
    ahead_.clear();
  }

  const TumDataset& dataset_;
  int threads_;
  int64_t end_;
  std::deque<std::pair<int64_t, std::future<LoadedFrame>>> ahead_;
};

}  // namespace rekon
