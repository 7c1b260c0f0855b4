// Any bytes on any channel: decoding never crashes, never leaks an exception,
// and a decoded frame_t with inline images either yields a valid frame or is
// dropped with a reason; a decoded mesh_blocks_t either yields its blocks or
// a rekon::Error.
#include <cstddef>
#include <cstdint>

#include "rekon/common/bus.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/common/messages.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/external_constraint_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/mesh_blocks_t.hpp"
#include "rekon_msgs/mesh_request_t.hpp"
#include "rekon_msgs/replay_end_t.hpp"
#include "rekon_msgs/replay_request_t.hpp"
#include "rekon_msgs/resume_point_t.hpp"
#include "rekon_msgs/service_stats_t.hpp"
#include "rekon_msgs/shutdown_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"
#include <spdlog/spdlog.h>

namespace {

template <class Msg>
bool decode(const uint8_t* data, size_t size, Msg* msg) {
  std::string why;
  return rekon::decodeMessage(data, static_cast<int>(size), msg, &why);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = [] {
    spdlog::set_level(spdlog::level::off);
    return true;
  }();
  (void)quiet;
  if (size < 1) return 0;
  const uint8_t kind = data[0] % 17;
  ++data;
  --size;
  switch (kind) {
    case 0: {
      rekon_msgs::frame_t m;
      if (decode(data, size, &m)) {
        m.shm_segment.clear();  // the fuzzer exercises inline images, not the host's /dev/shm
        rekon::FrameReceiver receiver;
        rekon::Intrinsics k;
        if (m.width > 0 && m.height > 0 && static_cast<int64_t>(m.width) * m.height <= (1 << 22)) receiver.receive(m, &k);
      }
      break;
    }
    case 1: {
      rekon_msgs::graph_update_t m;
      if (decode(data, size, &m)) {
        try {
          rekon::graphPoses(m);
        } catch (const rekon::Error&) {
        }
      }
      break;
    }
    case 2: { rekon_msgs::constraint_t m; if (decode(data, size, &m)) rekon::matrix6FromArray(m.information); break; }
    case 3: { rekon_msgs::tracked_frame_t m; if (decode(data, size, &m)) rekon::fromMsg(m.pose_in_keyframe); break; }
    case 4: { rekon_msgs::keyframe_t m; decode(data, size, &m); break; }
    case 5: { rekon_msgs::heartbeat_t m; decode(data, size, &m); break; }
    case 6: { rekon_msgs::frame_ack_t m; decode(data, size, &m); break; }
    case 7: { rekon_msgs::end_of_stream_t m; decode(data, size, &m); break; }
    case 8: { rekon_msgs::service_stats_t m; decode(data, size, &m); break; }
    case 9: { rekon_msgs::shutdown_t m; decode(data, size, &m); break; }
    case 10: { rekon_msgs::done_t m; decode(data, size, &m); break; }
    case 11: { rekon_msgs::resume_point_t m; decode(data, size, &m); break; }
    case 12: { rekon_msgs::replay_request_t m; decode(data, size, &m); break; }
    case 13: { rekon_msgs::replay_end_t m; decode(data, size, &m); break; }
    case 14: {
      rekon_msgs::mesh_blocks_t m;
      if (decode(data, size, &m)) {
        try {
          rekon::MeshMap map;
          map.apply(m);
          map.toMesh();
        } catch (const rekon::Error&) {
        }
      }
      break;
    }
    case 15: { rekon_msgs::mesh_request_t m; decode(data, size, &m); break; }
    default: {
      rekon_msgs::external_constraint_t m;
      if (decode(data, size, &m)) {
        rekon::fromMsg(m.pose);
        rekon::matrix6FromArray(m.information);
      }
      break;
    }
  }
  return 0;
}
