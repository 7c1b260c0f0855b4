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
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/service.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"

namespace rekon {

int listenMain(int argc, char** argv) {
  return runService(
      argc, argv, "listener", "Receives frames like a consumer and writes 'frame_id timestamp hash' per frame.",
      [](ArgParser& args) { args.option("frames-out", "file for one line per received frame (required)"); },
      [](ServiceContext& ctx) {
        const std::string path = ctx.args().get("frames-out");
        if (path.empty()) throw Error("--frames-out is required; see rekon listen --help");
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
          rekon_msgs::frame_ack_t ack{};
          ack.service = ctx.name();
          ack.frame_id = msg.frame_id;
          ctx.bus().publish(channel::kFrameAck, ack);
          ctx.setLastFrame(msg.frame_id);
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
