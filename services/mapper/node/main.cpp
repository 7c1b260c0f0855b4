// rekon-mapper: the mapping service (see mapper_service.hpp).
#include "mapper_service.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "mapper",
      "Fuses tracked frames into KF keyframes, integrates them into the TSDF volume, re-integrates them on pose-graph "
      "updates and writes <out>/mesh.ply.",
      nullptr, [](rekon::ServiceContext& ctx) { rekon::mapper::runMapperService(ctx); });
}
