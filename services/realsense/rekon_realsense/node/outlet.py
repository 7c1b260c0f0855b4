"""What a live frame source does around sending frames, as
common/src/frame_source.cpp and consumer_watch.hpp do for rekon-camera:
waiting for the consumers' heartbeats, then the live outlet: offer() never
blocks, the newest frame wins (the one it replaces is counted in
frames_dropped), a sending thread passes the waiting frame on as soon as
fewer than transport.live_in_flight sent frames are unacknowledged, the
newest sent frame goes out again when acknowledgements stall for a second,
and frames the source itself was too late for are counted in
frames_skipped_late. It also measures the capture-to-pose latency (capture
time to the tracker's tracked_frame_t for it), with every sample a row of
<out>/<service>_latency.csv, with sent_ms (capture to the frame sent: in
the ring or encoded, and published) and send_ms (the sending itself)."""
import bisect
import logging
import os
import threading
import time

from rekon_msgs import end_of_stream_t, frame_ack_t, heartbeat_t, tracked_frame_t

log = logging.getLogger("rekon")

FRAMES, FRAME_ACK, END_OF_STREAM, TRACKED_FRAMES, HEARTBEAT = (
    "FRAMES", "FRAME_ACK", "END_OF_STREAM", "TRACKED_FRAMES", "HEARTBEAT")
# Without any acknowledgement for this long the newest sent frame goes out again.
RESEND_AFTER_S = 1.0


class ConsumerWatch:
    """Who is alive where (a service counts once past "starting"), under which
    pid (a new one is a restart), and how far each has acknowledged."""

    ACKED, RESTARTED, STALLED, STOPPED = "acked", "restarted", "stalled", "stopped"

    def __init__(self, bus):
        self._cv = threading.Condition()
        self._hosts = {}
        self._pids = {}
        self._superseded = {}
        self._acked = {}
        self._last_frames = {}
        self._restarted = set()
        self._last_ack = time.monotonic()
        bus.subscribe(HEARTBEAT, heartbeat_t, self._on_heartbeat)
        bus.subscribe(FRAME_ACK, frame_ack_t, self._on_ack)

    def _on_heartbeat(self, hb):
        if hb.state == "starting":
            return
        with self._cv:
            pid = self._pids.get(hb.service)
            if pid is not None and pid != hb.pid:
                if hb.pid in self._superseded.setdefault(hb.service, set()):
                    return  # a killed instance's late heartbeat
                self._superseded[hb.service].add(pid)
                self._restarted.add(hb.service)
            self._pids[hb.service] = hb.pid
            self._hosts[hb.service] = hb.host
            self._last_frames[hb.service] = hb.last_frame_id
            self._cv.notify_all()

    def _on_ack(self, ack):
        with self._cv:
            if ack.frame_id > self._acked.get(ack.service, -1):
                self._acked[ack.service] = ack.frame_id
                self._last_ack = time.monotonic()
            self._cv.notify_all()

    def wait_for_heartbeats(self, names, timeout_s, ctx):
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while True:
                missing = [n for n in names if n not in self._hosts]
                if not missing or time.monotonic() >= deadline or ctx.stop_requested():
                    return missing
                self._cv.wait(0.1)

    def wait_for_ack(self, names, frame_id, stall_s, ctx):
        start = time.monotonic()
        with self._cv:
            while not ctx.stop_requested():
                if self._restarted:
                    return self.RESTARTED
                if min((self._acked.get(n, -1) for n in names), default=frame_id) >= frame_id:
                    return self.ACKED
                if time.monotonic() - max(start, self._last_ack) > stall_s:
                    return self.STALLED
                self._cv.wait(0.05)
        return self.STOPPED

    def last_frame(self, name):
        """The newest frame `name` has had, as its heartbeat says (-1: none, or not heard)."""
        with self._cv:
            return self._last_frames.get(name, -1)

    def all_on_host(self, names, host):
        with self._cv:
            return all(self._hosts.get(n) == host for n in names)

    def set_acked(self, name, frame_id):
        with self._cv:
            self._acked[name] = frame_id

    def take_restarts(self):
        with self._cv:
            r, self._restarted = self._restarted, set()
            return r


def wait_for_consumers(ctx, watch, consumers, timeout_s, wait_for_key):
    if not consumers:
        return
    ctx.set_state("waiting for consumers")
    missing = watch.wait_for_heartbeats(consumers, timeout_s, ctx)
    if missing and not ctx.stop_requested():
        from ..errors import Error
        raise Error(f"no heartbeat from rekon-{missing[0]} within {int(timeout_s)} s; start it, or remove it from "
                    f"{wait_for_key}")


def announce_end_of_stream(bus, last_frame_id, frames, duration_s):
    eos = end_of_stream_t()
    eos.last_frame_id = last_frame_id
    eos.frames = frames
    eos.duration_s = duration_s
    for _ in range(3):  # an end of stream lost on the wire must not leave a consumer waiting
        bus.publish(END_OF_STREAM, eos)
        time.sleep(0.05)


def quantile(sorted_values, q):
    """The q-quantile of sorted values by linear interpolation."""
    if not sorted_values:
        return 0.0
    x = q * (len(sorted_values) - 1)
    i = int(x)
    j = min(i + 1, len(sorted_values) - 1)
    return sorted_values[i] + (sorted_values[j] - sorted_values[i]) * (x - i)


class LiveOutlet:
    """offer(frame_id, frame, age_s): the sender thread passes the newest
    frame to send(frame_id, frame) (FrameSender.send). Counts as LiveOutlet::Counts.
    `append`: a restarted source adds its latency rows to the killed one's."""

    def __init__(self, ctx, watch, consumers, in_flight, send, append=False):
        self.ctx = ctx
        self._send = send
        self.watch = watch
        self.consumers = list(consumers)
        self.in_flight = max(1, in_flight)
        self._cv = threading.Condition()
        self._waiting = None  # (frame_id, frame)
        self._stopping = False
        self._error = None
        self.offered = self.sent = self.dropped = self.skipped_late = 0
        self.newest_sent = -1
        self._unacked = []
        self._capture = {}  # frame id -> monotonic capture time, sent and not yet tracked
        self._sent_at = {}  # frame id -> (monotonic time send() returned, ms spent in it)
        self._latencies = []
        self._started = time.monotonic()
        self._csv = None
        self._csv_flushed = time.monotonic()
        if ctx.out_dir:
            path = os.path.join(ctx.out_dir, f"{ctx.name}_latency.csv")
            fresh = not (append and os.path.exists(path) and os.path.getsize(path) > 0)
            self._csv = open(path, "w" if fresh else "a", encoding="utf-8")
            if fresh:
                self._csv.write("frame_id,captured_s,latency_ms,sent_ms,send_ms\n")
        ctx.bus.subscribe(TRACKED_FRAMES, tracked_frame_t, self._on_tracked)
        for key in ("frames_captured", "frames_sent", "frames_dropped", "frames_skipped_late"):
            ctx.set_live(key, 0)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _on_tracked(self, msg):
        now = time.monotonic()
        with self._cv:
            captured = self._capture.get(msg.frame_id)
            if captured is not None:
                ms = (now - captured) * 1e3
                bisect.insort(self._latencies, ms)
                if self._csv:
                    sent_at, send_ms = self._sent_at.get(msg.frame_id, (now, 0.0))
                    self._csv.write(f"{msg.frame_id},{captured - self._started:.6f},{ms:.3f},"
                                    f"{(sent_at - captured) * 1e3:.3f},{send_ms:.3f}\n")
                    if now - self._csv_flushed > 1.0:
                        self._csv.flush()
                        self._csv_flushed = now
            for k in [k for k in self._capture if k <= msg.frame_id]:
                del self._capture[k]
                self._sent_at.pop(k, None)

    def _room(self, newest_sent):
        with self._cv:
            if not self.consumers or len(self._unacked) < self.in_flight:
                return True
            oldest_in_window = self._unacked[len(self._unacked) - self.in_flight]
        r = self.watch.wait_for_ack(self.consumers, oldest_in_window, RESEND_AFTER_S, self.ctx)
        if r == ConsumerWatch.ACKED:
            with self._cv:
                self._unacked = [i for i in self._unacked if i > oldest_in_window]
                return len(self._unacked) < self.in_flight
        if r == ConsumerWatch.RESTARTED:
            for service in self.watch.take_restarts():
                log.warning("rekon-%s restarted: it continues from the next frame (a live source cannot send old "
                            "ones)", service)
                self.watch.set_acked(service, self.newest_sent)
        elif r == ConsumerWatch.STALLED and newest_sent is not None:
            log.debug("no acknowledgement for %.0f s: sending frame %d again", RESEND_AFTER_S, newest_sent[0])
            self._send(*newest_sent)
        return False

    def _run(self):
        try:
            newest_sent = None
            while True:
                with self._cv:
                    self._cv.wait_for(lambda: self._waiting is not None or self._stopping)
                    if self._waiting is None or self.ctx.stop_requested():
                        return
                if not self._room(newest_sent):
                    continue  # the waiting frame may have been replaced meanwhile
                with self._cv:
                    newest_sent, self._waiting = self._waiting, None
                started = time.monotonic()
                self._send(*newest_sent)
                done = time.monotonic()
                self.ctx.last_frame = newest_sent[0]
                with self._cv:
                    self._sent_at[newest_sent[0]] = (done, (done - started) * 1e3)
                    self._unacked.append(newest_sent[0])
                    self.sent += 1
                    self.newest_sent = newest_sent[0]
                self.ctx.set_live("frames_sent", self.sent)
        except Exception as e:  # passed on to the source's thread by offer() or finish()
            with self._cv:
                self._error = e
            self.ctx.request_stop()

    def _raise_sender_error(self):
        if self._error is not None:
            e, self._error = self._error, None
            raise e

    def offer(self, frame_id, frame, age_s=0.0):
        captured = time.monotonic() - min(max(age_s, 0.0), 10.0)
        with self._cv:
            self._raise_sender_error()
            if self._waiting is not None:
                self.dropped += 1
            self.offered += 1
            self._capture[frame_id] = captured
            if len(self._capture) > 4096:  # poses that never came
                self._sent_at.pop(min(self._capture), None)
                del self._capture[min(self._capture)]
            self._waiting = (frame_id, frame)
            self._cv.notify_all()
        self.ctx.set_live("frames_captured", self.offered)
        self.ctx.set_live("frames_dropped", self.dropped)

    def skipped(self, n):
        if n <= 0:
            return
        with self._cv:
            self.skipped_late += n
        self.ctx.set_live("frames_skipped_late", self.skipped_late)

    def finish(self, timeout_s):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self.ctx.stop_requested():
            with self._cv:
                if self._waiting is None:
                    break
            time.sleep(0.01)
        with self._cv:
            if self._waiting is not None:
                self.dropped += 1
            self._waiting = None
            self._stopping = True
            self._cv.notify_all()
        self.ctx.set_live("frames_dropped", self.dropped)
        self._thread.join()
        with self._cv:
            self._raise_sender_error()
        left = deadline - time.monotonic()
        if self.newest_sent >= 0 and left > 0 and self.consumers:
            self.watch.wait_for_ack(self.consumers, self.newest_sent, left, self.ctx)

    def close(self):
        with self._cv:
            self._stopping = True
            self._waiting = None
            self._cv.notify_all()
        self._thread.join()
        if self._csv:
            with self._cv:
                self._csv.close()
                self._csv = None

    def write_stats(self, stats):
        with self._cv:
            stats.update(frames_captured=self.offered, frames_sent=self.sent, frames_dropped=self.dropped,
                         frames_skipped_late=self.skipped_late, latency_samples=len(self._latencies))
            if self._latencies:
                stats["latency_ms_p50"] = quantile(self._latencies, 0.5)
                stats["latency_ms_p95"] = quantile(self._latencies, 0.95)
