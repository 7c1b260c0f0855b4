"""A Python frame source for the tests: the frames of a TUM folder on FRAMES, inline (PNG depth and color encoded
by rekon.bus from numpy pixels), each after the previous one was acknowledged by WAIT_FOR, then END_OF_STREAM.

    python frame_source.py DATASET WAIT_FOR
"""
import sys
import time
from pathlib import Path

from rekon.bus import Bus
from rosbag_writer import png_pixels, read_camera, read_index

dataset, wait_for = Path(sys.argv[1]), sys.argv[2]
cam = read_camera(dataset / "camera.yaml")
intrinsics = [cam[k] for k in ("width", "height", "fx", "fy", "cx", "cy")]
bus = Bus()
seen = {"alive": False, "acked": -1}


def on_heartbeat(channel, h):
    seen["alive"] = seen["alive"] or h.service == wait_for


def on_ack(channel, a):
    if a.service == wait_for:
        seen["acked"] = max(seen["acked"], a.frame_id)


bus.subscribe("HEARTBEAT", on_heartbeat)
bus.subscribe("FRAME_ACK", on_ack)
if not bus.run(timeout_s=30, until=lambda: seen["alive"]):
    sys.exit(f"frame_source: no heartbeat from {wait_for}")
frames = list(zip(read_index(dataset / "rgb.txt"), read_index(dataset / "depth.txt")))
for i, ((stamp, rgb), (_, depth)) in enumerate(frames):
    bus.publish_frame(i, float(stamp), intrinsics, png_pixels(dataset / depth), png_pixels(dataset / rgb),
                      cam["depth_scale"])
    if not bus.run(timeout_s=10, until=lambda: seen["acked"] >= i):
        sys.exit(f"frame_source: frame {i} was not acknowledged by {wait_for}")
first, last = float(frames[0][0][0]), float(frames[-1][0][0])
for _ in range(3):  # UDP may drop one
    bus.publish_end_of_stream(len(frames) - 1, len(frames), last - first)
    time.sleep(0.05)
