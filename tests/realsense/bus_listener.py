"""Run inside a private network namespace by test_lifecycle.py: starts
rekon-realsense (argv after --) and listens to it on the bus: its heartbeat
states in order, its STATS messages, the frames it sends (decoded as the C++
services decode frame_t: the images' sizes and intrinsics); with
--shutdown-after N it publishes SHUTDOWN once N frames came. Prints one JSON
object."""
import argparse
import json
import subprocess
import sys
import threading
import time

import lcm
from rekon_msgs import frame_t, heartbeat_t, service_stats_t, shutdown_t
from rekon_schema import SCHEMA_VERSION

p = argparse.ArgumentParser()
p.add_argument("--shutdown-after", type=int, default=0)
p.add_argument("command", nargs=argparse.REMAINDER)
a = p.parse_args()
lc = lcm.LCM("udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304")
seen = {"states": [], "stats": [], "frames": [], "shutdown_sent_after": None}


def on_heartbeat(_, data):
    hb = heartbeat_t.decode(data)
    if hb.service == "realsense" and (not seen["states"] or seen["states"][-1] != hb.state):
        seen["states"].append(hb.state)


def on_stats(_, data):
    m = service_stats_t.decode(data)
    if m.service == "realsense":
        seen["stats"].append(json.loads(m.json))


def on_frame(_, data):
    f = frame_t.decode(data)
    seen["frames"].append({"id": f.frame_id, "schema": f.schema_version == SCHEMA_VERSION, "w": f.width,
                           "h": f.height, "fx": f.fx, "depth_scale": f.depth_scale, "depth_bytes": len(f.depth_png),
                           "color_bytes": len(f.color), "color_format": f.color_format, "t": f.timestamp})
    if a.shutdown_after and len(seen["frames"]) == a.shutdown_after:
        m = shutdown_t()
        m.schema_version = SCHEMA_VERSION
        m.reason = "interrupted"
        lc.publish("REKON_SHUTDOWN", m.encode())
        seen["shutdown_sent_after"] = len(seen["frames"])


lc.subscribe("REKON_HEARTBEAT", on_heartbeat)
lc.subscribe("REKON_STATS", on_stats)
lc.subscribe("REKON_FRAMES", on_frame)
stop = threading.Event()


def spin():
    while not stop.is_set():
        lc.handle_timeout(50)


t = threading.Thread(target=spin)
t.start()
time.sleep(0.3)
proc = subprocess.run(a.command[1:] if a.command[:1] == ["--"] else a.command, stdout=subprocess.PIPE,
                      stderr=subprocess.STDOUT, text=True, timeout=120)
time.sleep(0.5)  # the exit heartbeat and the last STATS
stop.set()
t.join()
seen.update(rc=proc.returncode, log=proc.stdout)
print(json.dumps(seen))
