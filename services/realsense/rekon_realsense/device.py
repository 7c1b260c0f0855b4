"""An Intel RealSense D4xx (or its .bag recording) through Intel's SDK,
pyrealsense2: color and depth at one mode, depth aligned to color by the SDK
(rs.align), intrinsics and depth units read from the device (or the
recording), never typed in; each frame stamped with the device's own
timestamp mapped onto the host's wall clock (DeviceClock, as rekon-camera's).
Every failure to open is one line naming the device or file and what to do."""
import datetime
import logging
import os
import time

import numpy as np

from .errors import Error

log = logging.getLogger("rekon")

# A live device that delivers nothing for this long is lost (a D4xx sends 30
# frames a second; the SDK itself gives up on a frame after 5 s).
LOST_AFTER_S = 5.0
# Framesets the SDK holds for the capture loop: 100 ms at 30 Hz absorbs a
# hiccup of the Python loop (a collection, a busy core) without a loss; when
# it is full the SDK drops a frameset (a gap in the frame numbers: skipped
# late), never blocks the device.
QUEUE_FRAMESETS = 3
# A playback that stops further than this before its recorded duration, in a
# file that no longer opens, was cut short: to rekon a device that vanished.
# One that plays to its end has read to within microseconds of its duration
# (3.885679 s of 3.885676 s measured); a cut one stops where the file ends
# (1.8 s of 3.9 s for a file cut to half its bytes). The file is asked as well
# because the position is read as frames are taken: a loop stalled for the
# last half second of a recording has not seen its reader reach the end.
RECORDING_END_SLACK_S = 0.5
# A restarted playback seeks to this long before the frame after the one its
# consumers have, by the device clock: the seek lands within the SDK's read-ahead
# (a queue of 3 framesets, 0.1-0.2 s) of the time asked for, and the frames up
# to that one are then not taken (forward-only frame numbers), so none is missed.
RESUME_EARLY_S = 0.5
PRESETS = {"custom": 0, "default": 1, "hand": 2, "high_accuracy": 3, "high_density": 4, "medium_density": 5}
COLOR_FORMATS = ("rgb8", "bgr8")


def import_sdk():
    """pyrealsense2, or one line saying how to get it."""
    try:
        import pyrealsense2 as rs
    except ImportError:
        raise Error("Intel's RealSense SDK (the pyrealsense2 package) is not installed in this Python "
                    "environment; run tools/rekon deps (it installs python/requirements.txt from PyPI)") from None
    return rs


def host_wall_seconds():
    return time.time()


class DeviceClock:
    """Maps the device's frame timestamps onto the host's wall clock by the lower
    envelope of host - device (services/camera/include/rekon/camera/device_clock.hpp):
    stamps as steady as the device's, never later than the arrival."""

    MAX_DRIFT_PPM = 200.0
    MAX_DELAY_S = 0.5

    def __init__(self):
        self.offset = None
        self.last_device_s = 0.0
        self.resets = 0

    def stamp(self, device_s, arrival_s):
        observed = arrival_s - device_s
        jumped = self.offset is not None and (device_s < self.last_device_s or device_s - self.last_device_s > 10.0)
        if self.offset is None or jumped or observed - self.offset > self.MAX_DELAY_S:
            if self.offset is not None:
                self.resets += 1
            self.offset = observed
        else:
            drift = (device_s - self.last_device_s) * self.MAX_DRIFT_PPM * 1e-6
            self.offset = min(self.offset + drift, observed)
        self.last_device_s = device_s
        return device_s + self.offset


class Frame:
    """A captured frame: `timestamp` is its device time on the host clock,
    `arrival` the host time the SDK handed it over, `aligned` the host time
    once aligned and copied (the stage times of realsense_frames.csv)."""
    __slots__ = ("depth", "color_rgb", "timestamp", "device_ms", "number", "arrival", "aligned")

    def __init__(self, depth, color_rgb, timestamp, device_ms, number, arrival=0.0, aligned=0.0):
        self.depth, self.color_rgb, self.timestamp, self.device_ms, self.number = (
            depth, color_rgb, timestamp, device_ms, number)
        self.arrival, self.aligned = arrival or timestamp, aligned or timestamp


class Capture:
    FRAME, TIMEOUT, ENDED, LOST = "frame", "timeout", "ended", "lost"

    def __init__(self, status, frame=None, reason=""):
        self.status, self.frame, self.reason = status, frame, reason


def _info(rs, dev, what):
    return dev.get_info(what) if dev.supports(what) else ""


def _mode_text(profiles):
    return ", ".join(f"{str(p.stream_type()).split('.')[-1]} {p.as_video_stream_profile().width()}x"
                     f"{p.as_video_stream_profile().height()}@{p.fps()} {str(p.format()).split('.')[-1]}"
                     for p in profiles)


def list_devices():
    """One dict per connected RealSense (what --list prints)."""
    rs = import_sdk()
    out = []
    for dev in rs.context().query_devices():
        out.append({k: _info(rs, dev, getattr(rs.camera_info, k))
                    for k in ("name", "serial_number", "firmware_version", "usb_type_descriptor")})
    return out


class RealSenseSource:
    """Opens a device (`serial`, "" for the only one) or a recording (`playback`)."""

    def __init__(self, params):
        config = self._resolve(params)
        rs = self.rs
        self.clock = DeviceClock()
        self.replaced = 0
        self.incomplete = 0
        self.timestamp_domain = ""
        self._first_number = self._last_number = None
        self._taken = 0
        self._position_s = 0.0  # a playback's furthest position read, from its start
        self._resume = None  # a restarted playback: (device frame number, device ms) its consumers have
        self._last_frame_at = time.monotonic()
        try:
            self.queue = rs.frame_queue(QUEUE_FRAMESETS, keep_frames=True)
            self.profile = self.pipeline.start(config, self.queue)
        except RuntimeError as e:
            raise Error(f"{self.what}: the SDK cannot start {self.mode} ({e}); is another program using the camera? "
                        "close it, or re-plug the camera") from None
        dev = self.profile.get_device()
        if self.playback:
            self.pb = dev.as_playback()
            self.pb.set_real_time(True)  # at the recorded rate, as the camera delivered it
        depth_sensor = dev.first_depth_sensor()
        self._apply_options(depth_sensor)
        self.depth_units_m = depth_sensor.get_depth_scale()
        color = self.profile.get_stream(rs.stream.color).as_video_stream_profile()
        self.k = color.get_intrinsics()
        self.color_format = str(color.format()).split(".")[-1]
        self.align = rs.align(rs.stream.color)
        if any(abs(c) > 1e-6 for c in self.k.coeffs) and str(self.k.model).split(".")[-1] != "none":
            log.warning("%s: the color stream has %s distortion %s; rekon assumes a pinhole camera and ignores it",
                        self.what, str(self.k.model).split(".")[-1], [round(c, 5) for c in self.k.coeffs])

    @classmethod
    def check(cls, params):
        """What would be opened (the device or the recording, and the mode),
        found without starting it: rekon run's preflight. Each failure is the
        service's own line."""
        source = cls.__new__(cls)
        source._resolve(params)
        return f"{source.what}: {source.mode}"

    # ---- opening -------------------------------------------------------
    def _resolve(self, params):
        self.rs = import_sdk()
        self.params = params
        self.playback = params.playback
        self.pipeline = self.rs.pipeline()
        config = self.rs.config()
        if self.playback:
            self._open_recording(config)
        else:
            self._open_device(config)
        return config

    def _open_recording(self, config):
        rs, path = self.rs, self.playback
        if not os.path.isfile(path):
            raise Error(f"{path}: no such RealSense recording; give the path of a .bag file (rekon-realsense-write "
                        "makes one from a dataset)")
        self.what = path
        try:
            config.enable_device_from_file(path, repeat_playback=False)
            recorded = config.resolve(rs.pipeline_wrapper(self.pipeline))
        except RuntimeError as e:
            raise Error(f"{path}: not a readable RealSense .bag recording (SDK: {e}); record it with the RealSense "
                        "Viewer, rs-record or rekon-realsense-write") from None
        streams = recorded.get_streams()
        self.device = recorded.get_device()
        kinds = {str(s.stream_type()).split(".")[-1]: s for s in streams}
        if "depth" not in kinds:
            raise Error(f"{path}: the recording has no depth stream (it holds {_mode_text(streams) or 'nothing'}); "
                        "record depth and color together")
        if "color" not in kinds:
            raise Error(f"{path}: the recording has no color stream (it holds {_mode_text(streams)}); "
                        "record depth and color together")
        p = self.params
        self.mode = f"{p.width}x{p.height}@{p.fps}"
        for kind in ("depth", "color"):
            v = kinds[kind].as_video_stream_profile()
            if (v.width(), v.height(), v.fps()) != (p.width, p.height, p.fps):
                raise Error(f"{path}: mode {self.mode} is not in the recording (it holds {_mode_text(streams)}); set "
                            "realsense.width, realsense.height and realsense.fps to the recorded mode")
        color_format = str(kinds["color"].format()).split(".")[-1]
        if color_format not in COLOR_FORMATS:
            raise Error(f"{path}: color is recorded as {color_format}; rekon-realsense reads rgb8 or bgr8 color")
        config.enable_stream(rs.stream.depth, p.width, p.height, rs.format.z16, p.fps)
        config.enable_stream(rs.stream.color, p.width, p.height, getattr(rs.format, color_format), p.fps)

    def _open_device(self, config):
        rs, p = self.rs, self.params
        devices = list(rs.context().query_devices())
        serials = [_info(rs, d, rs.camera_info.serial_number) for d in devices]
        if not devices:
            raise Error("no RealSense camera found: plug a D4xx into a USB 3 port; as a user other than root install "
                        "Intel's udev rules (services/realsense/README.md); or play a recording with --playback "
                        "FILE.bag")
        if p.device:
            if p.device not in serials:
                raise Error(f"no RealSense camera with serial number {p.device} (connected: {', '.join(serials)}); "
                            "rekon-realsense --list shows them")
            self.device = devices[serials.index(p.device)]
        elif len(devices) > 1:
            raise Error(f"{len(devices)} RealSense cameras are connected ({', '.join(serials)}); choose one with "
                        "--device SERIAL (realsense.device)")
        else:
            self.device = devices[0]
        serial = _info(rs, self.device, rs.camera_info.serial_number)
        self.what = f"RealSense {_info(rs, self.device, rs.camera_info.name)} {serial}"
        self.mode = f"{p.width}x{p.height}@{p.fps}"
        config.enable_device(serial)
        config.enable_stream(rs.stream.depth, p.width, p.height, rs.format.z16, p.fps)
        config.enable_stream(rs.stream.color, p.width, p.height, rs.format.rgb8, p.fps)
        usb = _info(rs, self.device, rs.camera_info.usb_type_descriptor)
        if not config.can_resolve(rs.pipeline_wrapper(self.pipeline)):
            offered = set()
            for sensor in self.device.query_sensors():
                for prof in sensor.get_stream_profiles():
                    if prof.stream_type() in (rs.stream.depth, rs.stream.color) and prof.is_video_stream_profile():
                        v = prof.as_video_stream_profile()
                        offered.add(f"{v.width()}x{v.height()}@{v.fps()}")
            usb_note = (f"; the camera is on USB {usb}: 640x480 at 30 Hz needs a USB 3 port and cable"
                        if usb.startswith("2") else "")
            raise Error(f"{self.what}: mode {self.mode} (depth z16 and color rgb8) is not offered{usb_note}; it offers "
                        f"{', '.join(sorted(offered)) or 'none'}: set realsense.width, realsense.height, realsense.fps")
        if usb.startswith("2"):
            log.warning("%s is on USB %s: plug it into a USB 3 port (blue) with a USB 3 cable; USB 2 limits modes and "
                        "drops frames", self.what, usb)

    def _apply_options(self, sensor):
        rs, p = self.rs, self.params
        settable = not self.playback
        wanted = []
        if p.depth_units > 0:
            wanted.append(("depth_units", rs.option.depth_units, p.depth_units))
        if p.emitter in ("on", "off"):
            wanted.append(("emitter", rs.option.emitter_enabled, 1.0 if p.emitter == "on" else 0.0))
        if p.preset:
            wanted.append(("preset", rs.option.visual_preset, float(PRESETS[p.preset])))
        for name, option, value in wanted:
            if not settable:
                log.warning("realsense.%s is not applied to a recording (its options are recorded); ignored", name)
                continue
            if not sensor.supports(option):
                raise Error(f"{self.what} has no {name} option; remove realsense.{name}")
            try:
                sensor.set_option(option, value)
            except RuntimeError as e:
                r = sensor.get_option_range(option)
                raise Error(f"{self.what}: realsense.{name} {value:g} was refused ({e}); the device accepts "
                            f"{r.min:g} to {r.max:g}") from None
        self.emitter = self.preset = ""
        if sensor.supports(rs.option.emitter_enabled):
            self.emitter = "on" if sensor.get_option(rs.option.emitter_enabled) >= 0.5 else "off"
        if sensor.supports(rs.option.visual_preset):
            v = int(sensor.get_option(rs.option.visual_preset))
            self.preset = {n: k for k, n in PRESETS.items()}.get(v, str(v))

    def go_on_from(self, lost):
        """This source reopened after `lost` (the same device or recording)
        vanished: the device clock goes on, and a recording plays on from where
        it stopped, as a camera goes on streaming, its frames forward of the
        last one taken."""
        self.clock = lost.clock
        self.incomplete = lost.incomplete
        self.timestamp_domain = lost.timestamp_domain
        if self.playback and lost._position_s > 0:
            self.pb.seek(datetime.timedelta(seconds=lost._position_s))
            self._position_s = lost._position_s
            self._last_number = lost._last_number

    def _recording_opens(self):
        """Whether the SDK can open the recording now (a .bag cut short cannot:
        its index is at the end)."""
        try:
            config = self.rs.config()
            config.enable_device_from_file(self.playback, repeat_playback=False)
            return config.can_resolve(self.rs.pipeline_wrapper(self.rs.pipeline()))
        except RuntimeError:
            return False

    def resume_after(self, number, device_ms):
        """A restarted playback goes on after device frame `number` (at
        `device_ms`), the newest its consumers have from the killed instance:
        from a file nothing is missed. The first frameset tells where the
        recording is; it then seeks to just before that frame."""
        if self.playback:
            self._resume = (number, device_ms)

    # ---- what it is -----------------------------------------------------
    def info(self):
        rs, dev = self.rs, self.profile.get_device()
        return {
            "name": _info(rs, dev, rs.camera_info.name),
            "serial": _info(rs, dev, rs.camera_info.serial_number),
            "firmware": _info(rs, dev, rs.camera_info.firmware_version),
            "usb": _info(rs, dev, rs.camera_info.usb_type_descriptor),
            "mode": f"{self.mode} depth z16 aligned to color {self.color_format}",
            "depth_units_m": self.depth_units_m,
            "emitter": self.emitter,
            "preset": self.preset,
            "playback": self.playback,
        }

    def intrinsics(self):
        return {"width": self.k.width, "height": self.k.height, "fx": self.k.fx, "fy": self.k.fy,
                "cx": self.k.ppx, "cy": self.k.ppy, "depth_scale": 1.0 / self.depth_units_m}

    def describe(self):
        i = self.info()
        parts = [f"{i['name'] or 'RealSense'}", f"serial {i['serial'] or '-'}", f"firmware {i['firmware'] or '-'}",
                 f"USB {i['usb'] or '-'}", i["mode"], f"depth unit {self.depth_units_m * 1e3:.4g} mm",
                 f"emitter {i['emitter'] or '-'}", f"preset {i['preset'] or '-'}"]
        if self.playback:
            parts.insert(0, f"recording {self.playback}")
        return ", ".join(parts)

    # ---- frames ---------------------------------------------------------
    def next(self, timeout_s):
        try:
            ok, frames = self.queue.try_wait_for_frame(int(timeout_s * 1000))
        except RuntimeError as e:
            return Capture(Capture.LOST, reason=f"{self.what} stopped delivering frames (SDK: {e}); check the USB "
                                                "cable and port, then start again")
        if not ok:
            if self.playback:
                if self.pb.current_status() == self.rs.playback_status.stopped:
                    duration_s = self.pb.get_duration().total_seconds()
                    if duration_s - self._position_s > RECORDING_END_SLACK_S and not self._recording_opens():
                        return Capture(Capture.LOST, reason=(
                            f"{self.what}: the recording stopped at {self._position_s:.1f} s of its {duration_s:.1f} s "
                            "(the file was cut short or cannot be read); check the file, or record it again"))
                    return Capture(Capture.ENDED)
                self._position_s = max(self._position_s, self.pb.get_position() / 1e9)
            elif time.monotonic() - self._last_frame_at > LOST_AFTER_S:
                return Capture(Capture.LOST, reason=f"{self.what} delivered no frame for {LOST_AFTER_S:.0f} s; it was "
                                                    "unplugged or reset: check the USB cable and port, then start again")
            return Capture(Capture.TIMEOUT)
        arrival = host_wall_seconds()
        self._last_frame_at = time.monotonic()
        if self.playback:
            self._position_s = max(self._position_s, self.pb.get_position() / 1e9)
        frameset = frames.as_frameset()
        if not frameset.get_depth_frame() or not frameset.get_color_frame():
            self.incomplete += 1
            return Capture(Capture.TIMEOUT)
        # Frames the SDK dropped before this loop took them are the gaps in
        # the frame numbers; a frameset older than the newest taken (the
        # syncer let it through late, after a burst) is not sent: a live
        # source's frames go forward in time. Both are skipped late.
        number = frameset.get_color_frame().get_frame_number()
        if self._resume is not None:
            (self._last_number, resume_ms), self._resume = self._resume, None
            ahead_s = (resume_ms - frameset.get_color_frame().get_timestamp()) / 1e3 - RESUME_EARLY_S
            if ahead_s > 0:
                self.pb.seek(datetime.timedelta(seconds=self.pb.get_position() / 1e9 + ahead_s))
        if self._last_number is not None and number <= self._last_number:
            return Capture(Capture.TIMEOUT)
        if self._first_number is None:
            self._first_number = number
        self._last_number = number
        self._taken += 1
        self.replaced = (number - self._first_number + 1) - self._taken
        aligned = self.align.process(frameset)
        depth, color = aligned.get_depth_frame(), aligned.get_color_frame()
        device_ms = color.get_timestamp()
        if not self.timestamp_domain:
            self.timestamp_domain = str(color.get_frame_timestamp_domain()).split(".")[-1]
        stamp = self.clock.stamp(device_ms / 1e3, arrival)
        d = np.asanyarray(depth.get_data()).copy()
        c = np.asanyarray(color.get_data())
        c = (c[:, :, ::-1] if self.color_format == "bgr8" else c).copy()
        return Capture(Capture.FRAME, Frame(d, c, stamp, device_ms, number, arrival, host_wall_seconds()))

    def stop(self):
        try:
            self.pipeline.stop()
        except RuntimeError:
            pass
