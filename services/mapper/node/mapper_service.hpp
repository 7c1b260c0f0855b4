#pragma once
// rekon-mapper: the Mapper fed from the bus. The bus thread only copies
// frames, acknowledges them and queues work (inbox.hpp); one worker thread
// fuses, integrates and re-integrates (mapping_worker.hpp), so a
// re-integration never stalls frame intake; outputs.hpp writes what a run
// leaves.
#include <cstdint>

#include "rekon/common/service.hpp"

namespace rekon::mapper {

void runMapperService(ServiceContext& ctx);

}  // namespace rekon::mapper
