#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <exception>

#include "rekon/common/error.hpp"
#include "rekon/mapper/volume/volume_backend.hpp"

namespace rekon::volume {
namespace {

#ifdef REKON_VOLUME_WITH_CUDA
struct CudaVerdict {
  CudaProbe probe;
  std::string failure;  // why the CUDA backend cannot be trusted; empty when its self-check passed
  double check_ms = 0;
};

// Once per process, and only when a backend may be CUDA: probing creates a
// CUDA context, which costs time and GPU memory that `cpu` must not pay.
const CudaVerdict& cudaVerdict() {
  static const CudaVerdict verdict = [] {
    CudaVerdict v;
    v.probe = probeCudaDevices();
    if (v.probe.devices == 0) return v;
    const auto start = std::chrono::steady_clock::now();
    try {
      const std::unique_ptr<VolumeBackend> cpu = makeCpuBackend(0);
      const std::unique_ptr<VolumeBackend> cuda = makeCudaBackend();
      const std::string mismatch = compareBackendsOnSyntheticFrames(*cpu, *cuda);
      if (!mismatch.empty()) v.failure = "its result differs from the CPU backend's: " + mismatch;
    } catch (const std::exception& e) {
      v.failure = e.what();
    } catch (...) {
      v.failure = "a non-standard exception was thrown";
    }
    v.check_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    return v;
  }();
  return verdict;
}
#endif

}  // namespace

#ifdef REKON_VOLUME_WITH_CUDA
void logCudaCleanupFailure(const std::string& line) {
  // After a fault every later free fails the same way: the first one says it.
  static std::atomic<bool> logged{false};
  if (!logged.exchange(true)) spdlog::warn("{} (further failures to free GPU memory are not logged)", line);
}
#else
CudaProbe probeCudaDevices() {
  CudaProbe probe;
  probe.detail = "rekon was built without CUDA";
  return probe;
}
#endif

std::unique_ptr<VolumeBackend> makeBackend(const std::string& choice, int cpu_threads) {
  if (choice != "auto" && choice != "cpu" && choice != "cuda") {
    throw Error("volume backend '" + choice + "' is unknown; use auto, cpu or cuda");
  }
  if (choice == "cpu") {
    spdlog::info("volume: CPU backend (requested)");
    return makeCpuBackend(cpu_threads);
  }
#ifdef REKON_VOLUME_WITH_CUDA
  const CudaVerdict& v = cudaVerdict();
  if (v.probe.devices > 0 && v.failure.empty()) {
    spdlog::info("volume: CUDA backend ({} device(s); self-check against the CPU backend passed in {:.0f} ms)",
                 v.probe.devices, v.check_ms);
    return makeCudaBackend();
  }
  if (choice == "cuda") {
    if (v.probe.driver_error) {
      throw Error("volume.backend is cuda but the CUDA driver failed: " + v.probe.detail +
                  "; fix the driver installation or set volume.backend to auto or cpu");
    }
    if (v.probe.devices == 0) {
      throw Error("volume.backend is cuda but no CUDA device is present (" + v.probe.detail +
                  "); set volume.backend to auto or cpu");
    }
    throw Error("volume.backend is cuda but the CUDA backend failed its start-up self-check: " + v.failure +
                "; set volume.backend to cpu (or auto) and report this");
  }
  if (v.probe.driver_error) {
    spdlog::warn("volume: CPU backend, because of a CUDA driver error: {}", v.probe.detail);
  } else if (v.probe.devices == 0) {
    spdlog::info("volume: CPU backend (no CUDA device: {})", v.probe.detail);
  } else {
    spdlog::warn("volume: CPU backend, because the CUDA backend failed its start-up self-check: {}", v.failure);
  }
#else
  if (choice == "cuda") throw Error("volume backend 'cuda' requested but rekon was built without CUDA; use auto or cpu");
  spdlog::info("volume: CPU backend (built without CUDA)");
#endif
  return makeCpuBackend(cpu_threads);
}

std::vector<std::string> availableBackends() {
  std::vector<std::string> names{"cpu"};
  if (probeCudaDevices().devices > 0) names.push_back("cuda");
  return names;
}

}  // namespace rekon::volume
