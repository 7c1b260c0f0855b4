"""Rigid transforms as rekon writes them: 7 numbers (tx, ty, tz, qx, qy, qz, qw), translation in metres and a unit
quaternion, camera to world (TUM files, pose_t). numpy in and out."""

from __future__ import annotations

from pathlib import Path

import numpy as np

IDENTITY = np.array([0, 0, 0, 0, 0, 0, 1], dtype=np.float64)


def quat_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def rotate(q, v):
    """The vector v rotated by the unit quaternion q."""
    qv = np.array([*v, 0.0])
    conj = np.array([-q[0], -q[1], -q[2], q[3]])
    return quat_mul(quat_mul(q, qv), conj)[:3]


def compose(a, b):
    """a * b: the pose b expressed in a's parent frame (e.g. keyframe world pose * pose in keyframe)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    q = quat_mul(a[3:], b[3:])
    return np.concatenate([a[:3] + rotate(a[3:], b[:3]), q / np.linalg.norm(q)])


def inverse(a):
    a = np.asarray(a, float)
    conj = np.array([-a[3], -a[4], -a[5], a[6]])
    return np.concatenate([-rotate(conj, a[:3]), conj])


def between(a, b):
    """inverse(a) * b: b in a's frame."""
    return compose(inverse(a), b)


def angle_deg(a) -> float:
    """The rotation angle of a pose, degrees."""
    w = min(1.0, abs(float(a[6])) / np.linalg.norm(a[3:]))
    return float(np.degrees(2 * np.arccos(w)))


def read_tum(path) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps (N,), poses (N, 7)) of a TUM trajectory file ("timestamp tx ty tz qx qy qz qw" lines)."""
    rows = [line.split() for line in Path(path).read_text().splitlines() if line.strip() and not line.startswith("#")]
    table = np.array(rows, dtype=np.float64).reshape(-1, 8)
    return table[:, 0], table[:, 1:]


def write_tum(path, timestamps, poses) -> None:
    with open(path, "w") as f:
        for t, p in zip(timestamps, poses):
            f.write(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in p) + "\n")


class Trajectory:
    """A TUM trajectory looked up by time: the pose nearest a timestamp within max_dt (None when there is none)."""

    def __init__(self, path, max_dt: float = 0.02):
        self.timestamps, self.poses = read_tum(path)
        order = np.argsort(self.timestamps)
        self.timestamps, self.poses = self.timestamps[order], self.poses[order]
        self.max_dt = max_dt

    def at(self, timestamp: float):
        i = int(np.searchsorted(self.timestamps, timestamp))
        best = min((j for j in (i - 1, i) if 0 <= j < len(self.timestamps)),
                   key=lambda j: abs(self.timestamps[j] - timestamp), default=None)
        if best is None or abs(self.timestamps[best] - timestamp) > self.max_dt:
            return None
        return self.poses[best]
