#pragma once
// rekon-mapper: the Mapper fed from the bus. The bus thread only copies
// frames, acknowledges them and queues work; one worker thread fuses,
// integrates and re-integrates, so a re-integration never stalls frame intake.
#include <cstdint>

#include "rekon/common/service.hpp"

namespace rekon::mapper {

void runMapperService(ServiceContext& ctx);

}  // namespace rekon::mapper
