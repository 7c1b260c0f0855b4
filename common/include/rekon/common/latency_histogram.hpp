#pragma once
// Latencies in 1 ms bins up to 10 s (the last bin holds anything longer):
// fixed memory however long a session runs. The camera's capture-to-pose
// latency and the viewer's change-to-receipt latency use it.
#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>

namespace rekon {

class LatencyHistogram {
 public:
  void add(double ms) {
    const size_t bin = ms <= 0 ? 0 : std::min(bins_.size() - 1, static_cast<size_t>(ms));
    ++bins_[bin];
    ++count_;
  }
  int64_t count() const { return count_; }
  // The upper edge of the bin holding the q-quantile, in ms.
  double quantile(double q) const {
    const auto rank = static_cast<int64_t>(q * static_cast<double>(count_ - 1));
    int64_t seen = 0;
    for (size_t b = 0; b < bins_.size(); ++b) {
      seen += bins_[b];
      if (seen > rank) return static_cast<double>(b + 1);
    }
    return static_cast<double>(bins_.size());
  }

 private:
  std::array<int64_t, 10000> bins_{};
  int64_t count_ = 0;
};

}  // namespace rekon
