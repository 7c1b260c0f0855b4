// Any bytes as a depth PNG or a color image: a valid image or a rekon::Error,
// nothing else.
#include <spdlog/spdlog.h>

#include <cstddef>
#include <cstdint>

#include "rekon/common/error.hpp"
#include "rekon/common/image_io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  try {
    if (data[0] & 1) rekon::decodeDepthPng(data + 1, size - 1, 64, 48, "fuzz");
    else rekon::decodeColor(data + 1, size - 1, 64, 48, "fuzz");
  } catch (const rekon::Error&) {
  }
  return 0;
}
