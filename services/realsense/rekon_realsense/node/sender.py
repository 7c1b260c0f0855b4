"""Frames onto the bus, as common/src/frame_transport.cpp's FrameSender:
through the shared-memory frame ring (the frame_t names the slot; consumers
on this host) or inline in the frame_t (netpbm or PNG; any host). With
transport.mode auto the ring is used when every consumer's heartbeat comes
from this host, as rekon-camera chooses."""
import logging
import socket

from rekon_msgs import frame_t

from .. import frame_ring
from ..images import encode
from .outlet import FRAMES

log = logging.getLogger("rekon")


def choose_transport(mode, consumers, watch):
    """"shm" or "lcm" for transport.mode `mode` (chooseTransport in common/src/frame_source.cpp)."""
    if mode == "lcm":
        return "lcm"
    if not frame_ring.supported():
        if mode == "shm":
            log.warning("transport.mode shm: a Python writer of the frame ring needs an x86-64 CPU (its seqlock "
                        "relies on the order of its stores); sending frames inline over LCM")
        return "lcm"
    if mode == "shm":
        return "shm"
    local = bool(consumers) and watch.all_on_host(consumers, socket.gethostname())
    log.info("transport auto: %s", "shm (every consumer is on this host)" if local else "inline LCM")
    return "shm" if local else "lcm"


class FrameSender:
    """send(frame_id, frame): one frame_t on FRAMES, its images in ring slot
    frame_id % slots (written here, on the outlet's sending thread, so the ring
    holds only frames sent) or inline."""

    def __init__(self, bus, transport, params, k):
        self.bus, self.transport, self.k, self.encoding = bus, transport, k, params.encoding
        self.ring = None
        if transport == "shm":
            self.ring = frame_ring.FrameRingWriter(params.segment, params.slots, params.max_width, params.max_height,
                                                   log)

    def send(self, frame_id, frame):
        k = self.k
        m = frame_t()
        m.frame_id = frame_id
        m.timestamp = frame.timestamp
        m.width, m.height = k["width"], k["height"]
        m.fx, m.fy, m.cx, m.cy, m.depth_scale = k["fx"], k["fy"], k["cx"], k["cy"], k["depth_scale"]
        if self.ring:
            m.shm_slot = frame_id % self.ring.slots
            m.shm_generation = self.ring.write(m.shm_slot, frame_id, frame.timestamp, frame.depth, frame.color_rgb)
            m.shm_segment = self.ring.name
            m.depth_png, m.color, m.color_format = b"", b"", ""
        else:
            m.shm_segment, m.shm_slot, m.shm_generation = "", -1, 0
            m.depth_png, m.color, m.color_format = encode(frame.depth, frame.color_rgb, self.encoding)
        m.depth_png_size, m.color_size = len(m.depth_png), len(m.color)
        self.bus.publish(FRAMES, m)

    def close(self):
        if self.ring:
            self.ring.close()
