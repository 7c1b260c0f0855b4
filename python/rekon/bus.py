"""rekon's LCM bus from Python: subscribe to any channel and get the decoded message; publish frames (a Python
program can be a frame source) and external constraints. Channel names are given without the prefix
(lcm.channel_prefix, REKON_): bus.subscribe("MESH_BLOCKS", f).

    bus = Bus()                                   # lcm.url of config/default.yaml
    bus.subscribe("GRAPH_UPDATES", lambda channel, msg: print(msg.version))
    bus.run(timeout_s=10)                         # handle messages for 10 s (or until bus.stop())
"""

from __future__ import annotations

import os
import select
import time
from typing import Callable

import numpy as np

from . import msgs, png, schema_version

# lcm.url and lcm.channel_prefix of config/default.yaml (rekon run's bus).
DEFAULT_URL = "udpm://239.255.76.67:7667?ttl=0"
DEFAULT_PREFIX = "REKON_"
# As common/src/bus.cpp: a 4 MiB UDP receive buffer (the kernel's default, about 200 KB, holds less than one inline
# frame or a large mesh update, so a receiver busy for a moment loses messages; capped at net.core.rmem_max) and
# up to 1024 messages of a channel waiting for dispatch (liblcm's default: 30).
RECV_BUF_OPTION = "recv_buf_size=4194304"
QUEUE_CAPACITY = 1024


class DecodeError(Exception):
    pass


def message_types() -> dict[bytes, type]:
    """Every generated rekon_msgs type by its 8-byte fingerprint (what starts each encoded message)."""
    m = msgs()
    out = {}
    for name in dir(m):
        cls = getattr(m, name)
        if isinstance(cls, type) and hasattr(cls, "_get_packed_fingerprint"):
            out[cls._get_packed_fingerprint()] = cls
    return out


_TYPES: dict[bytes, type] | None = None


def decode(data: bytes):
    """The rekon_msgs message in `data`, whatever its type (found by its fingerprint)."""
    global _TYPES
    if _TYPES is None:
        _TYPES = message_types()
    cls = _TYPES.get(bytes(data[:8]))
    if cls is None:
        raise DecodeError(f"{len(data)} bytes whose fingerprint {bytes(data[:8]).hex()} is no rekon_msgs type "
                          f"(another program on the bus, or a build of other schemas)")
    try:
        return cls.decode(data)
    except Exception as err:  # noqa: BLE001 - generated decoders raise struct.error, ValueError, ...
        raise DecodeError(f"{cls.__name__} does not decode ({err})") from None


class Bus:
    def __init__(self, url: str | None = None, prefix: str = DEFAULT_PREFIX):
        import lcm

        self.url = with_receive_buffer(url or os.environ.get("REKON_LCM_URL") or DEFAULT_URL)
        self.prefix = prefix
        self.lcm = lcm.LCM(self.url)
        self.schema_version = schema_version()
        self.decode_errors = 0
        self._stop = False

    def subscribe(self, channel: str, callback: Callable[[str, object], None]):
        """callback(channel without prefix, decoded message) for each message on `channel` (a regex is allowed,
        ".*" for all). A message that does not decode is counted (decode_errors), never passed on."""

        def handler(full_channel, data):
            try:
                msg = decode(data)
            except DecodeError:
                self.decode_errors += 1
                return
            callback(full_channel[len(self.prefix):] if full_channel.startswith(self.prefix) else full_channel, msg)

        subscription = self.lcm.subscribe(self.prefix + channel, handler)
        subscription.set_queue_capacity(QUEUE_CAPACITY)
        return subscription

    def unsubscribe(self, subscription) -> None:
        self.lcm.unsubscribe(subscription)

    def publish(self, channel: str, msg) -> None:
        if hasattr(msg, "schema_version") and not msg.schema_version:
            msg.schema_version = self.schema_version
        self.lcm.publish(self.prefix + channel, msg.encode())

    def handle(self, timeout_s: float) -> bool:
        """Handles the messages that arrive within timeout_s; True when one did."""
        return self.lcm.handle_timeout(max(0, int(timeout_s * 1000))) > 0

    def run(self, timeout_s: float | None = None, until: Callable[[], bool] | None = None,
            tick: Callable[[], None] | None = None) -> bool:
        """Handles messages until `until()` is true, stop() is called, or timeout_s passes (False then).
        tick() runs about every 100 ms (a heartbeat, a deadline)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        self._stop = False
        while not self._stop and not (until and until()):
            if deadline is not None and time.monotonic() >= deadline:
                return False
            readable, _, _ = select.select([self.lcm.fileno()], [], [], 0.1)
            if readable:
                self.lcm.handle()
            if tick:
                tick()
        return True

    def stop(self) -> None:
        self._stop = True

    # -- publishing frames: a Python frame source -------------------------------------------------------------

    def publish_frame(self, frame_id: int, timestamp: float, intrinsics, depth: np.ndarray | bytes,
                      color: np.ndarray | bytes, depth_scale: float, color_format: str = "png") -> None:
        """One inline frame_t on FRAMES (messages/frame.lcm). intrinsics: (width, height, fx, fy, cx, cy).
        depth: (h, w) uint16 depth values (depth_scale per metre), or the bytes of a 16-bit PNG.
        color: (h, w, 3) uint8 RGB, or the bytes of a JPEG/PNG file (say which with color_format)."""
        f = msgs().frame_t()
        f.schema_version = self.schema_version
        f.frame_id = int(frame_id)
        f.timestamp = float(timestamp)
        f.width, f.height = int(intrinsics[0]), int(intrinsics[1])
        f.fx, f.fy, f.cx, f.cy = (float(v) for v in intrinsics[2:6])
        f.depth_scale = float(depth_scale)
        f.shm_segment, f.shm_slot, f.shm_generation = "", 0, 0
        f.depth_png = depth if isinstance(depth, (bytes, bytearray)) else png_bytes(depth)
        f.depth_png_size = len(f.depth_png)
        if isinstance(color, (bytes, bytearray)):
            f.color, f.color_format = bytes(color), color_format
        else:
            f.color, f.color_format = png_bytes(color), "png"
        f.color_size = len(f.color)
        self.publish("FRAMES", f)

    def publish_end_of_stream(self, last_frame_id: int, frames: int, duration_s: float) -> None:
        e = msgs().end_of_stream_t()
        e.schema_version, e.last_frame_id, e.frames, e.duration_s = self.schema_version, last_frame_id, frames, duration_s
        self.publish("END_OF_STREAM", e)

    # -- external constraints (messages/external_constraint.lcm, `rekon constrain`) ---------------------------

    def publish_constraint(self, *, to_id: int, pose, information, from_id: int = -1, source: str = "python",
                           sequence: int = 0) -> None:
        """A loop edge (from_id >= 0: pose of to_id in from_id) or an absolute pose prior (from_id -1: world pose of
        to_id). pose: (tx, ty, tz, qx, qy, qz, qw); information: 6x6 (order tx ty tz rx ry rz), positive definite."""
        m = msgs()
        c = m.external_constraint_t()
        c.schema_version = self.schema_version
        c.source, c.sequence = source, int(sequence)
        c.kind = c.KIND_LOOP if from_id >= 0 else c.KIND_PRIOR
        c.from_id, c.to_id = int(from_id), int(to_id)
        c.pose = make_pose(pose)
        info = np.asarray(information, dtype=float).reshape(36)
        c.information = [float(v) for v in info]
        self.publish("EXTERNAL_CONSTRAINTS", c)


def with_receive_buffer(url: str) -> str:
    if not url.startswith("udpm://") or "recv_buf_size" in url:
        return url
    return url + ("&" if "?" in url else "?") + RECV_BUF_OPTION


def make_pose(p):
    """pose_t from (tx, ty, tz, qx, qy, qz, qw)."""
    pose = msgs().pose_t()
    pose.t = [float(v) for v in p[:3]]
    pose.q = [float(v) for v in p[3:7]]
    return pose


def png_bytes(pixels: np.ndarray) -> bytes:
    """A PNG of (h, w) uint16 (16-bit grey), (h, w) uint8 or (h, w, 3) uint8 RGB pixels."""
    return png.encode(np.ascontiguousarray(pixels))
