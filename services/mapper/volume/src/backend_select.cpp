#include <spdlog/spdlog.h>

#include "rekon/common/error.hpp"
#include "rekon/volume/volume_backend.hpp"

namespace rekon::volume {

std::unique_ptr<VolumeBackend> makeBackend(const std::string& choice, int cpu_threads) {
  if (choice != "auto" && choice != "cpu" && choice != "cuda") {
    throw Error("volume backend '" + choice + "' is unknown; use auto, cpu or cuda");
  }
#ifdef REKON_VOLUME_WITH_CUDA
  const int devices = cudaDeviceCount();
  if (choice == "cuda" || (choice == "auto" && devices > 0)) {
    if (devices == 0) throw Error("volume backend 'cuda' requested but no CUDA device is present; use auto or cpu");
    spdlog::info("volume: CUDA backend ({} device(s) found)", devices);
    return makeCudaBackend();
  }
  spdlog::info("volume: CPU backend ({} backend requested, {} CUDA device(s) found)", choice, devices);
#else
  if (choice == "cuda") throw Error("volume backend 'cuda' requested but rekon was built without CUDA; use auto or cpu");
  spdlog::info("volume: CPU backend (built without CUDA)");
#endif
  return makeCpuBackend(cpu_threads);
}

std::vector<std::string> availableBackends() {
  std::vector<std::string> names{"cpu"};
#ifdef REKON_VOLUME_WITH_CUDA
  if (cudaDeviceCount() > 0) names.push_back("cuda");
#endif
  return names;
}

}  // namespace rekon::volume
