"""What a Python frontend needs to keep messages/FRONTEND.md: a service on the bus with rekon's lifecycle (heartbeat
and stats once a second under its name, stop on SHUTDOWN), and one call per thing a frontend publishes: keyframes (FC2),
tracked frames (FC9), graph updates (FC6, FC7), acknowledgements (FC8) and done (FC10), with schema_version (FC1)
and finite unit-quaternion poses (FC4) checked before they go out.

    node = Frontend("replay")                       # player.wait_for must name it (e.g. [replay, mapper])
    node.on_frame = lambda frame: ...               # frame_t (FRAMES); node.on_end = lambda eos: ...
    node.run()                                      # until node.stop() or SHUTDOWN
"""

from __future__ import annotations

import json
import math
import os
import socket
import time

import numpy as np

from . import msgs
from .bus import Bus, make_pose

HEARTBEAT_PERIOD_S = 1.0
# done_t is sent this many times, this far apart: UDP may drop one (FC10).
DONE_REPEATS = 3
DONE_GAP_S = 0.05


class FrontendError(Exception):
    pass


def checked_pose(pose, what: str):
    p = np.asarray(pose, dtype=float).reshape(7)
    if not np.all(np.isfinite(p)) or abs(np.linalg.norm(p[3:]) - 1.0) > 1e-6:
        raise FrontendError(f"{what}: pose {p.tolist()} is not finite with a unit quaternion (FC4)")
    return make_pose(p)


class Frontend:
    def __init__(self, name: str, bus: Bus | None = None):
        self.name = name
        self.bus = bus or Bus()
        self.m = msgs()
        self.pid = os.getpid()
        self.host = socket.gethostname()
        self.state = "starting"
        self.last_frame_id = -1
        self.keyframes: dict[int, np.ndarray] = {}  # announced keyframe id -> newest world pose
        self.graph_version = 0
        self.stats: dict = {}  # published on STATS once a second and at exit (the stats.json keys of a service)
        self.on_frame = None
        self.on_end = None
        self._next_heartbeat = 0.0
        self.bus.subscribe("FRAMES", lambda channel, frame: self.on_frame and self.on_frame(frame))
        self.bus.subscribe("END_OF_STREAM", lambda channel, eos: self.on_end and self.on_end(eos))
        self.bus.subscribe("SHUTDOWN", lambda channel, msg: self.stop())

    # -- lifecycle ------------------------------------------------------------------------------------------
    def heartbeat(self, state: str | None = None) -> None:
        if state:
            self.state = state
        h = self.m.heartbeat_t()
        h.service, h.pid, h.host, h.utime = self.name, self.pid, self.host, int(time.time() * 1e6)
        h.last_frame_id, h.state = self.last_frame_id, self.state
        self.bus.publish("HEARTBEAT", h)
        st = self.m.service_stats_t()
        st.service, st.utime = self.name, h.utime
        st.json = json.dumps({"frames": self.last_frame_id + 1, "keyframes": len(self.keyframes), **self.stats})
        self.bus.publish("STATS", st)
        self._next_heartbeat = time.monotonic() + HEARTBEAT_PERIOD_S

    def _tick(self) -> None:
        if time.monotonic() >= self._next_heartbeat:
            self.heartbeat()

    def run(self, timeout_s: float | None = None) -> bool:
        """Heartbeats and handles messages until stop() (or SHUTDOWN); then says "exited". False on timeout."""
        self.heartbeat("running")
        try:
            return self.bus.run(timeout_s=timeout_s, tick=self._tick)
        finally:
            self.heartbeat("exited")

    def stop(self) -> None:
        self.bus.stop()

    # -- what a frontend publishes -------------------------------------------------------------------------
    def keyframe(self, keyframe_id: int, frame_id: int, timestamp: float, pose_world) -> None:
        """FC2: a new keyframe with its world pose, before any tracked frame names it; FC3: each id once."""
        if keyframe_id in self.keyframes:
            raise FrontendError(f"keyframe {keyframe_id} was announced already (FC3)")
        k = self.m.keyframe_t()
        k.keyframe_id, k.frame_id, k.timestamp = int(keyframe_id), int(frame_id), float(timestamp)
        k.pose_world = checked_pose(pose_world, f"keyframe {keyframe_id}")
        self.keyframes[int(keyframe_id)] = np.asarray(pose_world, float)
        self.bus.publish("KEYFRAMES", k)

    def tracked(self, frame_id: int, timestamp: float, keyframe_id: int, pose_in_keyframe=None,
                covariance=None) -> None:
        """FC9: the frame's pose in its keyframe (STATE_OK), or lost when pose_in_keyframe is None."""
        t = self.m.tracked_frame_t()
        t.frame_id, t.timestamp = int(frame_id), float(timestamp)
        if pose_in_keyframe is None:
            t.keyframe_id, t.state = -1, t.STATE_LOST
            t.pose_in_keyframe = make_pose([0, 0, 0, 0, 0, 0, 1])
        else:
            if keyframe_id not in self.keyframes:
                raise FrontendError(f"frame {frame_id} names keyframe {keyframe_id}, never announced (FC2)")
            t.keyframe_id, t.state = int(keyframe_id), t.STATE_OK
            t.pose_in_keyframe = checked_pose(pose_in_keyframe, f"frame {frame_id}")
        t.covariance = [float(v) for v in (np.zeros(36) if covariance is None else np.asarray(covariance).reshape(36))]
        self.last_frame_id = max(self.last_frame_id, int(frame_id))
        self.bus.publish("TRACKED_FRAMES", t)

    def graph_update(self, poses: dict | None = None, final: bool = False) -> None:
        """FC6/FC7: every announced keyframe's world pose (the announced ones, moved by `poses`), a newer version."""
        for kf_id, pose in (poses or {}).items():
            if kf_id not in self.keyframes:
                raise FrontendError(f"a graph update names keyframe {kf_id}, never announced (FC6)")
            self.keyframes[kf_id] = np.asarray(pose, float)
        self.graph_version += 1
        g = self.m.graph_update_t()
        g.version, g.final_update = self.graph_version, bool(final)
        ids = sorted(self.keyframes)
        g.num_keyframes, g.keyframe_ids = len(ids), ids
        g.poses = [checked_pose(self.keyframes[i], f"keyframe {i}") for i in ids]
        self.bus.publish("GRAPH_UPDATES", g)

    def ack(self, frame_id: int, service: str | None = None) -> None:
        """FC8: done with every frame up to frame_id, under the name the frame source waits for."""
        a = self.m.frame_ack_t()
        a.service, a.frame_id = service or self.name, int(frame_id)
        self.bus.publish("FRAME_ACK", a)

    def done(self, service: str = "optimiser") -> None:
        """FC10: this frontend's work for the stream is finished (the mapper's final pass starts on it)."""
        d = self.m.done_t()
        d.service, d.pid, d.last_frame_id = service, self.pid, self.last_frame_id
        for i in range(DONE_REPEATS):
            if i:
                time.sleep(DONE_GAP_S)
            self.bus.publish("DONE", d)


def moved(a, b, metres: float, degrees: float) -> bool:
    """Whether b is at least `metres` or `degrees` away from a (a keyframe rule)."""
    from .poses import angle_deg, between

    rel = between(a, b)
    return float(np.linalg.norm(rel[:3])) >= metres or angle_deg(rel) >= degrees or not math.isfinite(rel[0])
