#include "listen.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cinttypes>
#include <condition_variable>
#include <cstdio>
#include <fstream>
#include <mutex>
#include <thread>

#include "rekon/common/error.hpp"
#include "rekon/common/frame_ack.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/common/service.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/mesh_request_t.hpp"

namespace rekon {

namespace {

// --mesh: the mapper's surface from MESH_BLOCKS, assembled as a viewer does,
// written as PLY when the mapper is done (or at a stop).
void listenForMesh(ServiceContext& ctx, const std::string& path) {
  std::mutex mutex;
  std::condition_variable done_cv;
  MeshMap map;
  int64_t messages = 0, bytes = 0, rejected = 0, full_parts = 0, gaps = 0;
  int64_t last_sequence = -1, last_part = -1, last_parts = 0;
  bool done = false, gap_unanswered = false;
  StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
  ctx.bus().subscribe<rekon_msgs::mesh_blocks_t>(channel::kMeshBlocks, [&](const rekon_msgs::mesh_blocks_t& msg) {
    std::lock_guard<std::mutex> lock(mutex);
    // A part lost on the way (UDP) leaves blocks stale: ask for a snapshot.
    const bool follows = (msg.sequence == last_sequence && msg.part == last_part + 1) ||
                         (msg.part == 0 && (last_sequence < 0 || (msg.sequence == last_sequence + 1 && last_part == last_parts - 1)));
    if (!follows) {
      ++gaps;
      gap_unanswered = true;
    }
    last_sequence = msg.sequence;
    last_part = msg.part;
    last_parts = msg.parts;
    if (msg.full && msg.part == 0) gap_unanswered = false;
    try {
      map.apply(msg);
      ++messages;
      bytes += msg.getEncodedSize();
      full_parts += msg.full ? 1 : 0;
    } catch (const Error& e) {
      ++rejected;
      spdlog::warn("{}", e.what());
    }
  });
  ctx.bus().subscribe<rekon_msgs::done_t>(channel::kDone, [&](const rekon_msgs::done_t& msg) {
    std::lock_guard<std::mutex> lock(mutex);
    done = done || msg.service == "mapper";
    done_cv.notify_all();
  });
  ctx.setState("running");
  spdlog::info("listening for the mesh on {}", channel::kMeshBlocks);
  rekon_msgs::mesh_request_t request{};
  request.requester = ctx.name();
  std::unique_lock<std::mutex> lock(mutex);
  auto last_request = std::chrono::steady_clock::now() - std::chrono::hours(1);
  while (!done && !ctx.stopRequested()) {
    // Until a snapshot came (a mapper that starts after us misses the first request), and after a gap.
    if ((full_parts == 0 || gap_unanswered) && std::chrono::steady_clock::now() - last_request > std::chrono::seconds(2)) {
      ctx.bus().publish(channel::kMeshRequest, request);
      last_request = std::chrono::steady_clock::now();
    }
    done_cv.wait_for(lock, std::chrono::milliseconds(100));
  }
  const Mesh mesh = map.toMesh();
  writePly(mesh, path);
  spdlog::info("mesh from {} messages ({} bytes, {} rejected, {} gaps): {} blocks, {} vertices, {} triangles -> {}",
               messages, bytes, rejected, gaps, map.blockCount(), mesh.vertices.size(), mesh.triangles.size(), path);
  ctx.stats()
      .set("mesh_messages", static_cast<long long>(messages))
      .set("mesh_bytes", static_cast<long long>(bytes))
      .set("mesh_rejected", static_cast<long long>(rejected))
      .set("mesh_full_parts", static_cast<long long>(full_parts))
      .set("mesh_gaps", static_cast<long long>(gaps))
      .set("mesh_blocks", static_cast<long long>(map.blockCount()))
      .set("mesh_vertices", static_cast<long long>(mesh.vertices.size()))
      .set("mesh_triangles", static_cast<long long>(mesh.triangles.size()));
}

}  // namespace

int listenMain(int argc, char** argv) {
  return runService(
      argc, argv, "listener",
      "Receives frames like a consumer and writes 'frame_id timestamp hash' per frame; or, with --mesh, assembles the "
      "mapper's mesh from MESH_BLOCKS.",
      [](ArgParser& args) {
        args.option("frames-out", "file for one line per received frame");
        args.option("mesh", "PLY file for the mesh assembled from MESH_BLOCKS (asks for a full snapshot at start; "
                            "written when the mapper is done or at a stop)");
      },
      [](ServiceContext& ctx) {
        if (!ctx.args().get("mesh").empty()) return listenForMesh(ctx, ctx.args().get("mesh"));
        const std::string path = ctx.args().get("frames-out");
        if (path.empty()) throw Error("--frames-out or --mesh is required; see rekon listen --help");
        std::ofstream out(path);
        if (!out) throw Error(path + ": cannot write; check the folder");
        FrameReceiver receiver;
        std::mutex mutex;
        std::condition_variable done_cv;
        int64_t last_frame = -1, received = 0;
        bool done = false;
        StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
        ctx.bus().subscribe<rekon_msgs::frame_t>(channel::kFrames, [&](const rekon_msgs::frame_t& msg) {
          const auto frame = receiver.receive(msg, nullptr);
          std::lock_guard<std::mutex> lock(mutex);
          if (frame) {
            char line[96];
            std::snprintf(line, sizeof(line), "%" PRId64 " %.6f %016" PRIx64 "\n", frame->id, frame->timestamp, frameHash(*frame));
            out << line;
            ++received;
          }
          last_frame = std::max(last_frame, msg.frame_id);
          acknowledgeFrame(ctx, msg.frame_id);
        });
        ctx.bus().subscribe<rekon_msgs::end_of_stream_t>(channel::kEndOfStream, [&](const rekon_msgs::end_of_stream_t&) {
          std::lock_guard<std::mutex> lock(mutex);
          done = true;
          done_cv.notify_all();
        });
        ctx.setState("running");
        std::unique_lock<std::mutex> lock(mutex);
        while (!done && !ctx.stopRequested()) done_cv.wait_for(lock, std::chrono::milliseconds(100));
        spdlog::info("received {} frames (last id {}), dropped {}", received, last_frame, receiver.dropped());
        ctx.stats().set("frames", static_cast<long long>(received)).set("dropped", static_cast<long long>(receiver.dropped()));
      });
}

}  // namespace rekon
