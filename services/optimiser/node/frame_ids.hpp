#pragma once
// The frame ids the optimiser has heard, as runs of consecutive ids: frames
// come nearly in order, so an hour's 108,000 ids take a few runs, not a node
// each (the frames themselves go to the journal and are read back at the end).
#include <cstdint>
#include <iterator>
#include <map>

namespace rekon::optimiser {

class FrameIds {
 public:
  // False when `id` was there already.
  bool insert(int64_t id) {
    auto next = runs_.upper_bound(id);  // the first run starting after id
    if (next != runs_.begin()) {
      auto run = std::prev(next);
      if (id <= run->second) return false;
      if (id == run->second + 1) {  // extends the run before; perhaps joins it to the next
        run->second = id;
        if (next != runs_.end() && next->first == id + 1) {
          run->second = next->second;
          runs_.erase(next);
        }
        ++size_;
        return true;
      }
    }
    if (next != runs_.end() && next->first == id + 1) {  // extends the next run downwards
      const int64_t last = next->second;
      runs_.erase(next);
      runs_.emplace(id, last);
    } else {
      runs_.emplace(id, id);
    }
    ++size_;
    return true;
  }
  bool contains(int64_t id) const {
    auto next = runs_.upper_bound(id);
    return next != runs_.begin() && id <= std::prev(next)->second;
  }
  size_t size() const { return size_; }
  size_t runs() const { return runs_.size(); }

 private:
  std::map<int64_t, int64_t> runs_;  // first id -> last id
  size_t size_ = 0;
};

}  // namespace rekon::optimiser
