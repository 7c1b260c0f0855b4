#pragma once
// rekon-mapper: the Mapper fed from the bus. The bus thread only copies
// frames, acknowledges them and queues work; one worker thread fuses,
// integrates and re-integrates, so a re-integration never stalls frame intake.
#include <cstdint>

#include "rekon/common/service.hpp"

namespace rekon::mapper {

// Drops graph updates older than the newest seen (each update carries every
// keyframe's pose, so only the newest matters).
class GraphUpdateFilter {
 public:
  bool accept(int64_t version) {
    if (version <= newest_) return false;
    newest_ = version;
    return true;
  }
  int64_t newest() const { return newest_; }

 private:
  int64_t newest_ = -1;
};

void runMapperService(ServiceContext& ctx);

}  // namespace rekon::mapper
