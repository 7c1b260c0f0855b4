// Any text as a config file: a valid Config or a rekon::Error naming the
// problem, nothing else; every documented key reads back or fails the same way.
// The same text as a camera.yaml (parseIntrinsics): valid intrinsics or a
// rekon::Error.
#include <cstddef>
#include <cstdint>
#include <string>

#include "rekon/common/camera.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    rekon::parseIntrinsics(text, "camera.yaml").validate("camera.yaml");
  } catch (const rekon::Error&) {
  }
  try {
    const rekon::Config c = rekon::Config::fromYamlText(text);
    for (const char* key : {"transport.slots", "lcm.drop_fraction", "player.rate", "log.level", "player.wait_for"}) {
      try {
        c.getInt(key);
      } catch (const rekon::Error&) {
      }
      try {
        c.getDouble(key);
      } catch (const rekon::Error&) {
      }
      try {
        c.getStringList(key);
      } catch (const rekon::Error&) {
      }
    }
    c.dump();
  } catch (const rekon::Error&) {
  }
  return 0;
}
