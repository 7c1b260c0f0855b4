"""rekon-realsense: publishes an Intel RealSense camera's frames (or a .bag
recording's, at its recorded rate) on the rekon bus, in place of the player,
as rekon-camera does for OpenNI2 and libfreenect devices: it opens the device
once its consumers listen, sends frame_t through the live outlet (the newest
frame wins, never waits) with the images in the shared-memory frame ring or
inline, records every captured frame when asked, and ends the stream when the
recording ends, the device is lost, or the run stops."""
import logging
import os
import sys
import time

from ..errors import Error
from ..params import Params

log = logging.getLogger("rekon")


def load_calibration(path, k):
    """--calibration: camera.yaml's color intrinsics in place of the device's
    (for a camera recalibrated by hand); its size must be the mode's. The depth
    unit stays the device's: the depth values are the device's."""
    import yaml
    try:
        with open(path, encoding="utf-8") as f:
            c = yaml.safe_load(f)
    except OSError:
        raise Error(f"{path}: cannot read the calibration file; give a camera.yaml (width height fx fy cx cy)") from None
    except yaml.YAMLError:
        raise Error(f"{path}: not valid YAML; give a camera.yaml (width height fx fy cx cy)") from None
    try:
        fields = {key: float(c[key]) for key in ("width", "height", "fx", "fy", "cx", "cy")}
    except (TypeError, KeyError, ValueError):
        raise Error(f"{path}: needs width, height, fx, fy, cx and cy as numbers") from None
    if (int(fields["width"]), int(fields["height"])) != (k["width"], k["height"]):
        raise Error(f"{path} is for {int(fields['width'])}x{int(fields['height'])} but the camera runs at "
                    f"{k['width']}x{k['height']}; set realsense.width/height or give the calibration of this mode")
    if "depth_scale" in c and abs(float(c["depth_scale"]) - k["depth_scale"]) > 1e-3 * k["depth_scale"]:
        log.warning("%s: depth_scale %g ignored: the device's depth unit gives %g values per metre", path,
                    float(c["depth_scale"]), k["depth_scale"])
    out = dict(k)
    out.update(fx=fields["fx"], fy=fields["fy"], cx=fields["cx"], cy=fields["cy"])
    return out


class FrameLog:
    """<out>/realsense_frames.csv: per frame sent to the outlet, the device's
    frame number and timestamp (ms, in its domain) beside the host stamp the
    frame carries, so that a recording's frames can be found again; and where
    the source's share of the capture-to-pose latency goes: delivery_ms (the
    stamp to the SDK handing the frameset over) and align_ms (the SDK's align
    and the copies); the rest of it is in realsense_latency.csv (sent_ms,
    send_ms: the outlet's)."""

    def __init__(self, out_dir, append=False):
        path = os.path.join(out_dir, "realsense_frames.csv") if out_dir else ""
        # A restarted source adds its rows to the killed one's, which wrote
        # each row through at once (line-buffered: 30 writes a second) so that
        # a SIGKILL loses none of them.
        fresh = not (append and os.path.exists(path) and os.path.getsize(path) > 0)
        self.f = open(path, "w" if fresh else "a", encoding="utf-8", buffering=1) if out_dir else None
        if self.f and fresh:
            self.f.write("frame_id,device_frame_number,device_timestamp_ms,timestamp,delivery_ms,align_ms\n")

    def row(self, frame_id, frame):
        if self.f:
            self.f.write(f"{frame_id},{frame.number},{frame.device_ms:.6f},{frame.timestamp:.6f},"
                         f"{(frame.arrival - frame.timestamp) * 1e3:.3f},{(frame.aligned - frame.arrival) * 1e3:.3f}\n")

    def close(self):
        if self.f:
            self.f.close()


class CaptureEnd:
    """How a capture went: `lost` "" for the end of a recording or a stop, else
    the one line that says what happened to the device and what to do; the
    frame ids (continued by a restarted source); the outages it came back
    from; and `source`, the device as last opened (reopened after an outage)."""

    def __init__(self, source, first_id):
        self.source, self.first_id = source, first_id
        self.lost, self.frames = "", 0
        # The device time the frames span: the sum of its steps between them
        # (a step back or over 10 s is a clock reset, left out), so a stalled
        # host or SDK that made the host stamps jump never stretches it.
        self.device_span_s, self.last_device_ms = 0.0, None
        self.outages, self.frames_missed, self.outage_s = 0, 0, 0.0  # missed: at the device's rate while away

    def note_outages(self, ctx):
        for key, value in self.outage_stats().items():
            ctx.set_live(key, value)

    def outage_stats(self):
        return {"outages": self.outages, "outage_seconds": self.outage_s,
                "frames_missed_in_outages": self.frames_missed}


def reopen(ctx, params, lost, device_k, since):
    """The device (or recording) again after it was lost at `since`
    (monotonic): reopened with a doubling wait (realsense.reconnect_wait_s, at
    most 8 times that) until realsense.reconnect_timeout_s after `since`; None
    when it stays away, the run stops, or another camera (other intrinsics)
    answers. A recording plays on from where it stopped."""
    from ..device import RealSenseSource
    wait_s = params.reconnect_wait_s
    attempt = 0
    while not ctx.stop_requested():
        attempt += 1
        if time.monotonic() - since + wait_s > params.reconnect_timeout_s:
            return None
        if ctx.sleep(wait_s):
            return None
        try:
            source = RealSenseSource(params)
        except (Error, RuntimeError) as e:
            log.info("%s: attempt %d to reopen it failed (%s)", lost.what, attempt, e)
            wait_s = min(2 * wait_s, 8 * params.reconnect_wait_s)
            continue
        if source.intrinsics() != device_k:
            log.error("%s came back as another camera (intrinsics %s instead of %s); not using it", lost.what,
                      source.intrinsics(), device_k)
            source.stop()
            return None
        try:
            source.go_on_from(lost)
        except RuntimeError as e:
            log.info("%s: attempt %d to go on where it stopped failed (%s)", lost.what, attempt, e)
            source.stop()
            wait_s = min(2 * wait_s, 8 * params.reconnect_wait_s)
            continue
        return source
    return None


def capture(ctx, end, outlet, recorder, params, frame_log):
    """Takes frames until the recording ends, the device is lost for longer
    than realsense.reconnect_timeout_s, max_frames are captured, or the run
    stops; each frame's id after the last (end.first_id + frames so far)."""
    from ..device import Capture, host_wall_seconds
    start = last_report = time.monotonic()
    replaced_before = 0
    device_k = end.source.intrinsics()
    # Set while the device is away: until a frame comes again (one that opens
    # but sends nothing is not back). (monotonic, host wall clock)
    lost_at = None
    while not ctx.stop_requested() and (params.max_frames <= 0 or end.frames < params.max_frames):
        source = end.source
        c = source.next(0.5)
        if c.status == Capture.TIMEOUT:
            continue
        if c.status == Capture.ENDED:
            log.info("the recording has ended after %d frames", end.frames)
            break
        if c.status == Capture.LOST:
            outlet.skipped(source.replaced - replaced_before)
            replaced_before = source.replaced
            source.stop()  # the SDK lets go of the device (or file) before it is opened again
            reopened = None
            if params.reconnect_timeout_s > 0:
                if lost_at is None:
                    lost_at = (time.monotonic(), host_wall_seconds())
                    log.warning("%s; reopening it for up to %.0f s (realsense.reconnect_timeout_s)", c.reason,
                                params.reconnect_timeout_s)
                reopened = reopen(ctx, params, source, device_k, lost_at[0])
            if reopened is None:
                log.error("%s", c.reason)
                end.lost = c.reason
                break
            end.source, replaced_before = reopened, 0
            continue
        if lost_at is not None:
            away_s = host_wall_seconds() - lost_at[1]
            missed = int(away_s * params.fps)
            end.outages += 1
            end.frames_missed += missed
            end.outage_s += away_s
            end.note_outages(ctx)
            log.warning("%s is back after %.1f s (about %d frames missed); frame ids go on from %d", source.what,
                        away_s, missed, end.first_id + end.frames)
            lost_at = None
        # Frames the SDK delivered that a newer one replaced before this loop
        # took them (gaps in the device's frame numbers): skipped late.
        outlet.skipped(source.replaced - replaced_before)
        replaced_before = source.replaced
        f = c.frame
        frame_id = end.first_id + end.frames
        end.frames += 1
        if end.last_device_ms is not None and 0.0 < f.device_ms - end.last_device_ms < 10000.0:
            end.device_span_s += (f.device_ms - end.last_device_ms) / 1000.0
        end.last_device_ms = f.device_ms
        if recorder:
            recorder.push(f)
        frame_log.row(frame_id, f)
        outlet.offer(frame_id, f, host_wall_seconds() - f.timestamp)
        if time.monotonic() - last_report > 2.0:
            last_report = time.monotonic()
            log.info("captured %d frames (%.1f frames/s), sent %d, dropped %d, skipped late %d", outlet.offered,
                     outlet.offered / (last_report - start), outlet.sent, outlet.dropped, outlet.skipped_late)
    outlet.skipped(end.source.replaced - replaced_before)
    return end


def sent_before(out_dir, frame_id):
    """(device frame number, device ms) of frame `frame_id` in
    <out_dir>/realsense_frames.csv, as the instance that sent it last wrote it
    (a later instance reuses the ids an earlier one offered and never got
    across); None when it is not there."""
    found = None
    try:
        with open(os.path.join(out_dir, "realsense_frames.csv"), encoding="utf-8") as f:
            for line in f.read().splitlines()[1:]:
                cells = line.split(",")
                if len(cells) >= 3 and cells[0] == str(frame_id):
                    found = (int(cells[1]), float(cells[2]))
    except (OSError, ValueError):
        return None
    return found


def run_realsense(ctx):
    from ..device import RealSenseSource
    from .outlet import ConsumerWatch, LiveOutlet, announce_end_of_stream, wait_for_consumers
    from ..recorder import Recorder, save_intrinsics
    from .sender import FrameSender, choose_transport
    from .service import PeerWatch
    from ..device import import_sdk
    params = Params(ctx.config)
    import_sdk()  # said before waiting for anyone
    if params.playback and not os.path.isfile(params.playback):
        raise Error(f"{params.playback}: no such RealSense recording; give the path of a .bag file "
                    "(rekon-realsense-write makes one from a dataset)")
    watch = ConsumerWatch(ctx.bus)
    peers = PeerWatch(ctx.bus, ctx.lifecycle)
    # The device opens once its consumers listen: a camera cannot be paused,
    # so frames captured before would only be dropped.
    wait_for_consumers(ctx, watch, params.wait_for, params.wait_timeout_s, "realsense.wait_for")
    if ctx.stop_requested():
        return
    source = RealSenseSource(params)
    end = CaptureEnd(source, 0)
    outlet = recorder = sender = None
    frame_log = FrameLog(ctx.out_dir, append=params.restarted)
    try:
        k = source.intrinsics()
        if params.calibration:
            k = load_calibration(params.calibration, k)
        info = source.info()
        log.info("realsense: %s", source.describe())
        log.info("intrinsics %s (%s), %g depth values per metre", " ".join(
            f"{key} {k[key]:.6g}" for key in ("fx", "fy", "cx", "cy")),
            params.calibration or "from the " + ("recording" if params.playback else "device"), k["depth_scale"])
        if ctx.out_dir:
            save_intrinsics(k, os.path.join(ctx.out_dir, "camera.yaml"))  # the calibration in effect
        if params.record:
            recorder = Recorder(params.record, k, params.record_queue)
        transport = choose_transport(params.transport_mode, params.wait_for, watch)
        sender = FrameSender(ctx.bus, transport, params, k)
        outlet = LiveOutlet(ctx, watch, params.wait_for, params.in_flight, sender.send, append=params.restarted)
        ctx.set_state("capturing")
        # A restarted source (rekon run restarts a killed one) numbers its
        # frames after the newest its consumers have: an id from 0 again would
        # be taken for a frame they already had.
        if params.restarted:
            end.first_id = max([watch.last_frame(name) + 1 for name in params.wait_for] + [0])
            log.warning("restarted: the consumers have the frames up to %d; frame ids go on from %d", end.first_id - 1,
                        end.first_id)
            # A recording goes on after the frame they have (the killed
            # instance's realsense_frames.csv says which): nothing of a file
            # is missed. A camera sends what it sees now.
            had = sent_before(ctx.out_dir, end.first_id - 1) if params.playback and ctx.out_dir else None
            if had:
                log.info("the recording goes on after its frame %d (%.3f ms), the consumers' newest", *had)
                source.resume_after(*had)
            elif params.playback:
                log.info("the recording plays from its start: frame %d is not in realsense_frames.csv",
                         end.first_id - 1)
        end.note_outages(ctx)
        capture(ctx, end, outlet, recorder, params, frame_log)
        source = end.source
        lost, frames = end.lost, end.frames
        outlet.finish(params.wait_timeout_s)
        if recorder:
            recorder.close()
        s = ctx.stats
        outlet.write_stats(s)
        span = end.device_span_s * frames / (frames - 1) if frames > 1 else 0.0
        s.update(device=params.playback or params.device or info["serial"], serial=info["serial"],
                 name=info["name"], firmware=info["firmware"], usb=info["usb"], mode=info["mode"],
                 depth_units_m=info["depth_units_m"], emitter=info["emitter"], preset=info["preset"],
                 timestamp_domain=source.timestamp_domain, clock_resets=source.clock.resets,
                 frames_incomplete=source.incomplete, frames=outlet.sent, sequence_seconds=span,
                 transport=transport, encoding=params.encoding if transport == "lcm" else "",
                 end="end of stream" if not lost else "device lost: " + lost, **end.outage_stats())
        if params.restarted:
            s["restarted_at_frame"] = end.first_id
        if params.playback:
            s["playback"] = os.path.abspath(params.playback)
        if recorder:
            s.update(record_folder=params.record, frames_recorded=recorder.written,
                     record_dropped=recorder.dropped, record_failed=recorder.failed)
        log.info("captured %d frames: %d sent, %d dropped (the consumers were not ready), %d skipped late (replaced in "
                 "the SDK before they were taken)%s", outlet.offered, outlet.sent, outlet.dropped, outlet.skipped_late,
                 f", {recorder.written} recorded, {recorder.dropped + recorder.failed} not recorded (the disk did not "
                 "keep up)" if recorder else "")
        announce_end_of_stream(ctx.bus, outlet.newest_sent, outlet.sent, end.device_span_s)
        ctx.set_state("lingering")
        peers.wait_until_finished(params.wait_for, ctx)
    finally:
        end.source.stop()
        frame_log.close()
        if outlet:
            outlet.close()
        if sender:
            sender.close()
        if recorder:
            recorder.close()


def add_options(parser):
    parser.add_argument("--device", help="serial number of the camera to open when several are connected; "
                                         "overrides realsense.device")
    parser.add_argument("--playback", help="a .bag recording to play at its recorded rate instead of a camera; "
                                           "overrides realsense.playback")
    parser.add_argument("--calibration", help="camera.yaml with color intrinsics to use instead of the device's; "
                                              "overrides realsense.calibration")
    parser.add_argument("--record", help="record every captured frame into this new TUM folder; overrides "
                                         "realsense.record")
    parser.add_argument("--list", action="store_true", help="list the connected RealSense cameras and exit")
    parser.add_argument("--check", action="store_true", help="find the camera (or the recording, with its depth, "
                        "color and mode) without starting it, print what would be opened and exit: 0 when it "
                        "can be, else 1 and one line saying why (rekon run's preflight)")


def main(argv=None):
    from .service import run_service
    argv = sys.argv[1:] if argv is None else argv
    if "--list" in argv:
        return list_command()
    if "--check" in argv:
        return check_command(argv)

    def body(ctx):
        for key in ("device", "playback", "calibration", "record"):
            value = getattr(ctx.args, key)
            if value is not None:
                ctx.config.set(f"realsense.{key}", value)
        run_realsense(ctx)

    return run_service(argv, "realsense", "Publishes an Intel RealSense camera's frames (or a .bag recording's) on the "
                       "rekon bus, through Intel's SDK (pyrealsense2).", add_options, body,
                       epilog="examples:\n  rekon run --camera realsense --out out/live\n"
                              "  rekon run --camera realsense:123456789012 --set realsense.preset=high_accuracy --out OUT\n"
                              "  rekon run --camera realsense --playback scan.bag --out OUT\n"
                              "  rekon-realsense --list")


def check_command(argv):
    """--check: the options and config as the service reads them, the device or
    recording resolved through the SDK, nothing started and no bus opened."""
    import argparse
    from ..config import Config
    from ..device import RealSenseSource
    parser = argparse.ArgumentParser(prog="rekon-realsense --check")
    parser.add_argument("--check", action="store_true")
    parser.add_argument("--config", default="")
    parser.add_argument("--set", action="append", default=[])
    parser.add_argument("--device")
    parser.add_argument("--playback")
    args, _ = parser.parse_known_args(argv)
    try:
        config = Config.load(args.config, args.set)
        for key in ("device", "playback"):
            if getattr(args, key) is not None:
                config.set(f"realsense.{key}", getattr(args, key))
        params = Params(config)
        if params.playback and not os.path.isfile(params.playback):
            raise Error(f"{params.playback}: no such RealSense recording; give the path of a .bag file "
                        "(rekon-realsense-write makes one from a dataset)")
        print(RealSenseSource.check(params))
    except Error as e:
        print(f"rekon-realsense: error: {e}", file=sys.stderr)
        return 1
    return 0


def list_command():
    from ..device import list_devices
    try:
        devices = list_devices()
    except Error as e:
        print(f"rekon-realsense: error: {e}", file=sys.stderr)
        return 1
    if not devices:
        print("no RealSense camera connected (as a user other than root: Intel's udev rules, "
              "services/realsense/README.md)")
    for d in devices:
        print(f"realsense:{d['serial_number']}  {d['name']}  firmware {d['firmware_version']}  "
              f"USB {d['usb_type_descriptor']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
