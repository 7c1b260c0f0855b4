#pragma once
// What every frame source (rekon-player, rekon-camera) does around sending
// frames: waiting for its consumers, choosing the transport, announcing the
// end of the stream, and, for a source that cannot wait (a camera, or the
// player with `pacing: live`), the live outlet: the newest frame wins, no
// queue grows, frames the consumers were not ready for are dropped and
// counted, and so are the frames the source itself was too late to take.
#include <memory>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/consumer_watch.hpp"
#include "rekon/common/frame_transport.hpp"
#include "rekon/common/json.hpp"
#include "rekon/common/rgbd_frame.hpp"
#include "rekon/common/service.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"

namespace rekon {

// Waits for the heartbeats of `consumers`; throws naming the first one still
// silent after `timeout_s` and `wait_for_key`, the config key that lists them.
void waitForConsumers(ServiceContext& ctx, ConsumerWatch& watch, const std::vector<std::string>& consumers,
                      double timeout_s, const std::string& wait_for_key);

// transport.mode `mode`: "shm", "lcm", or "auto" (shm when every consumer's
// heartbeat comes from this host).
TransportMode chooseTransport(const std::string& mode, const std::vector<std::string>& consumers, ConsumerWatch& watch);

// Publishes `eos` three times: an end of stream lost on the wire must not
// leave a consumer waiting.
void announceEndOfStream(Bus& bus, const rekon_msgs::end_of_stream_t& eos);

// A live source after its end of stream: stays (state "lingering"; the frame
// ring lives as long as the sender) until the consumers are finished. A
// consumer restarted meanwhile (a mapper killed in its final pass) hears `eos`
// again: a live source has no frames to send it again, and without the end
// it would wait for ever.
void lingerAfterLiveEnd(ServiceContext& ctx, ConsumerWatch& watch, const PeerWatch& peers,
                        const std::vector<std::string>& consumers, const rekon_msgs::end_of_stream_t& eos);

// Sends the frames of a source that cannot be paused. offer() never blocks:
// the offered frame replaces the one waiting (which counts as dropped), and a
// sending thread passes the waiting frame on as soon as fewer than
// `in_flight` sent frames are unacknowledged by the consumers. Memory: one
// waiting frame, one copy of the newest sent (sent again when the
// acknowledgements stall: a frame or its acknowledgement was lost), and the
// capture times of the frames in flight.
// Also measures the capture-to-pose latency: from a frame's capture time to
// the tracker's tracked_frame_t for it, as this process receives it. With
// --out every latency is also a row of <out>/<service>_latency.csv
// (frame_id, captured_s: seconds from the outlet's start, latency_ms),
// flushed once a second: the curve of a long live run, kept if it is stopped.
// Two counts say what never reached the consumers, the same for every live
// source: `frames_skipped_late`, frames whose time passed before the source
// could take them (a starved or slow source: the player behind its clock, the
// camera's capture thread behind its driver), never offered; and
// `frames_dropped`, frames offered that the consumers were not ready for.
// frames_captured (offered) = frames_sent + frames_dropped.
// An exception on the sending thread (a frame larger than the ring slot, a
// bus error) ends that thread and requests a stop; the next offer() or
// finish() throws it on the source's thread, whose service logs it as one
// line and stops cleanly.
class LiveOutlet {
 public:
  struct Counts {
    int64_t offered = 0, sent = 0, dropped = 0, skipped_late = 0, newest_sent = -1;
  };

  LiveOutlet(ServiceContext& ctx, FrameSender& sender, ConsumerWatch& watch, std::vector<std::string> consumers,
             int in_flight);
  ~LiveOutlet();
  LiveOutlet(const LiveOutlet&) = delete;
  LiveOutlet& operator=(const LiveOutlet&) = delete;

  // `age_s`: seconds since the frame was captured (a driver's delay);
  // `frame.id` is kept (ids of dropped frames are gaps downstream).
  void offer(RgbdFrame frame, const Intrinsics& k, double age_s = 0.0);
  // `n` more frames were skipped for lateness (never offered).
  void skippedLate(int64_t n);
  // Sends the waiting frame, then waits up to `timeout_s` until the
  // consumers acknowledged every frame sent, and stops the sending thread.
  void finish(double timeout_s);
  Counts counts() const;
  // frames_captured, frames_sent, frames_dropped, frames_skipped_late and, once a pose came back,
  // latency_ms_p50 / latency_ms_p95 / latency_samples.
  void writeStats(JsonObject& stats) const;

 private:
  struct State;
  std::shared_ptr<State> state_;  // shared with the bus handler, which may outlive this object
};

// <out>/source_counts.csv of a source, a row a second and a last one at its
// end, so a stopped run keeps what its source did (rekon bench longrun reads
// it): frames due so far (the next frame's id), sent, dropped, skipped late,
// and the mean time the source took to make each frame since the row before
// (rendering it, or waiting for its decoding). An empty `out_dir` writes
// nothing.
class SourceCountsLog {
 public:
  explicit SourceCountsLog(const std::string& out_dir);
  ~SourceCountsLog();
  SourceCountsLog(const SourceCountsLog&) = delete;
  SourceCountsLog& operator=(const SourceCountsLog&) = delete;

  void frameMade(double ms);
  // Writes a row when a second has passed since the last (or `last_row`).
  void row(int64_t due, const LiveOutlet::Counts& c, bool last_row = false);

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace rekon
