"""rekon-realsense's parts that need no bus and no recording: the device clock,
the frame images, the config and its checks."""
import io

import numpy as np
import pytest
from PIL import Image

from rekon_realsense.config import Config
from rekon_realsense.device import DeviceClock
from rekon_realsense.errors import Error
from rekon_realsense.images import color_ppm, depth_pgm, encode
from rekon_realsense.params import Params


def test_device_clock_keeps_the_device_spacing_under_arrival_jitter():
    # 30 Hz device stamps; arrivals 5-25 ms late at random (USB, scheduling).
    rng = np.random.default_rng(1)
    clock = DeviceClock()
    device = np.arange(300) / 30.0
    arrival = 1000.0 + device + rng.uniform(0.005, 0.025, device.size)
    stamps = np.array([clock.stamp(d, a) for d, a in zip(device, arrival)])
    assert np.all(stamps <= arrival + 1e-9)  # never later than the frame arrived
    # After the first frames the envelope sits on the least delayed arrivals:
    # spacing as the device's within 1 ms (arrivals vary by 20 ms).
    assert np.max(np.abs(np.diff(stamps[30:]) - 1 / 30.0)) < 1e-3
    assert clock.resets == 0


def test_device_clock_reanchors_when_the_device_time_jumps_back():
    clock = DeviceClock()
    for i in range(10):
        clock.stamp(5.0 + i / 30.0, 100.0 + i / 30.0 + 0.01)
    s = clock.stamp(0.0, 100.5)  # a recording restarted: its clock begins again
    assert clock.resets == 1
    assert s == pytest.approx(100.5)


def test_depth_pgm_and_color_ppm_hold_the_pixels_exactly():
    rng = np.random.default_rng(2)
    depth = rng.integers(0, 65536, (48, 64), dtype=np.uint16)
    rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    assert np.array_equal(np.array(Image.open(io.BytesIO(depth_pgm(depth)))).astype(np.uint16), depth)
    assert np.array_equal(np.array(Image.open(io.BytesIO(color_ppm(rgb)))), rgb)
    d, c, fmt = encode(depth, rgb, "png")
    assert fmt == "png"
    assert np.array_equal(np.array(Image.open(io.BytesIO(d))).astype(np.uint16), depth)
    assert np.array_equal(np.array(Image.open(io.BytesIO(c))), rgb)


def test_an_unknown_config_key_is_an_error_naming_it():
    with pytest.raises(Error, match="realsense.laser"):
        Config.load("", ["realsense.laser=on"])


def test_emitter_off_reads_as_off_although_yaml_1_1_says_false():
    assert Params(Config.load("", ["realsense.emitter=off"])).emitter == "off"
    assert Params(Config.load("", ["realsense.emitter=on"])).emitter == "on"


@pytest.mark.parametrize("setting, named", [
    ("realsense.preset=very_accurate", "realsense.preset"),
    ("realsense.emitter=sometimes", "realsense.emitter"),
    ("realsense.depth_units=0.5", "realsense.depth_units"),
    ("realsense.encoding=jpeg", "realsense.encoding"),
    ("transport.live_in_flight=0", "transport.live_in_flight"),
    ("realsense.reconnect_wait_s=0", "realsense.reconnect_wait_s"),
    ("realsense.reconnect_timeout_s=-1", "realsense.reconnect_timeout_s"),
])
def test_a_bad_realsense_setting_is_one_line_naming_its_key(setting, named):
    with pytest.raises(Error) as e:
        Params(Config.load("", [setting]))
    assert named in str(e.value) and "\n" not in str(e.value)


def test_the_defaults_are_the_issues_mode():
    p = Params(Config.load())
    assert (p.width, p.height, p.fps) == (640, 480, 30)
    assert p.wait_for == ["tracker", "mapper"]


class _Frames:
    """A source double: `frames` frames 33 ms apart, then `end` (LOST or ENDED)."""

    def __init__(self, frames, end, reason="", device_ms=None):
        from rekon_realsense.device import Capture, Frame
        self.replaced = 0
        self.what = "RealSense D435 123"
        device_ms = device_ms or [i * 33.333 for i in range(frames)]
        self._script = [Capture(Capture.FRAME, Frame(np.zeros((480, 640), np.uint16), np.zeros((480, 640, 3), np.uint8),
                                                     1000.0 + i / 30, device_ms[i], i + 1)) for i in range(frames)]
        self._script.insert(1, Capture(Capture.TIMEOUT))  # a wait without a frame changes nothing
        self._script.append(Capture(end, reason=reason))

    def next(self, _timeout_s):
        return self._script.pop(0)

    def intrinsics(self):
        return {}

    def stop(self):
        pass


class _Outlet:
    def __init__(self):
        self.offered, self.sent, self.dropped, self.skipped_late, self.ids = 0, 0, 0, 0, []

    def offer(self, frame_id, frame, age_s):
        self.offered += 1
        self.ids.append(frame_id)

    def skipped(self, n):
        self.skipped_late += n


class _Ctx:
    def stop_requested(self):
        return False


def _capture(source, tmp_path, *settings):
    from rekon_realsense.node.main import CaptureEnd, FrameLog, capture
    outlet, log = _Outlet(), FrameLog(str(tmp_path))
    end = capture(_Ctx(), CaptureEnd(source, 0), outlet, None, Params(Config.load("", list(settings))), log)
    log.close()
    return (end.lost, end.frames, end.device_span_s), outlet


def test_a_lost_device_ends_the_capture_with_its_line_after_every_frame_before_it(tmp_path):
    line = "RealSense D435 123 stopped delivering frames (SDK: ...); check the USB cable and port, then start again"
    # Not reopened (realsense.reconnect_timeout_s 0): tests/realsense/test_crash_only.py reopens a recording.
    (lost, frames, span), outlet = _capture(_Frames(4, "lost", line), tmp_path, "realsense.reconnect_timeout_s=0")
    assert lost == line
    assert frames == 4 and outlet.ids == [0, 1, 2, 3]
    assert span == pytest.approx(0.1, abs=1e-5)  # the device's steps between the 4 frames (33.333 ms each)
    with open(tmp_path / "realsense_frames.csv") as f:
        assert len(f.readlines()) == 1 + 4  # header and every frame taken


def test_the_span_is_the_devices_steps_so_a_clock_reset_never_stretches_it(tmp_path):
    # 3 frames, the device's clock back to 0 (a reset), 2 more: 2 + 1 steps of 33 ms.
    (_, frames, span), _ = _capture(_Frames(5, "ended", device_ms=[0, 33.333, 66.667, 0, 33.333]), tmp_path)
    assert frames == 5 and span == pytest.approx(0.1, abs=1e-5)


def test_the_end_of_a_recording_is_a_clean_end(tmp_path):
    (lost, frames, _), outlet = _capture(_Frames(3, "ended"), tmp_path)
    assert lost == "" and frames == 3 and outlet.offered == 3
