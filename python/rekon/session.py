"""A session folder (`rekon run --session DIR`, services/mapper/src/store/SESSION.md) in Python: the camera and
volume, every KF keyframe (its anchor DVO keyframe, pose, frames and images), the DVO keyframes' newest poses, every
fused frame's world pose, and the mesh (by `rekon remesh`, the C++ integration).

    s = Session("out/7s_session")
    s.camera, len(s.keyframes), s.trajectory()     # (timestamps, poses (N, 7)) camera to world
    depth, weight, color = s.keyframe_images(s.keyframes[0].id)
    mesh = s.mesh()                                # rekon.mesh.Mesh
"""

from __future__ import annotations

import os
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import build_dir
from .mesh import Mesh, read_ply
from .poses import compose

SPILL_MAGIC = b"RKSPILL1"
SPILL_HEADER = np.dtype([("magic", "S8"), ("version", "<u4"), ("width", "<i4"), ("height", "<i4"),
                         ("reserved", "<u4"), ("id", "<i8"), ("payload_bytes", "<u8"), ("checksum", "<u8")])


class SessionError(Exception):
    """A missing or damaged session file: one line naming it."""


@dataclass
class Keyframe:
    id: int
    anchor: int          # the DVO keyframe it is anchored to
    first_frame: int
    last_frame: int
    frames: int
    timestamp: float
    pose_in_anchor: np.ndarray  # (7,)


def _rows(path: Path, columns: int) -> list[list[str]]:
    if not path.exists():
        raise SessionError(f"{path}: missing; is {path.parent} a session folder (rekon run --session DIR)?")
    rows = []
    for line in path.read_text().splitlines():
        w = line.split()
        if w and not w[0].startswith("#") and len(w) == columns:  # a line cut short (a killed run) is skipped
            rows.append(w)
    return rows


def _yaml_map(text: str, key: str) -> dict:
    for line in text.splitlines():
        if line.startswith(key + ":"):
            inner = line.split("{", 1)[1].rsplit("}", 1)[0]
            return {k.strip(): float(v) for k, v in (item.split(":") for item in inner.split(","))}
    raise SessionError(f"session.yaml has no '{key}'")


class Session:
    def __init__(self, path):
        self.path = Path(path)
        yaml_path = self.path / "session.yaml"
        if not yaml_path.exists():
            raise SessionError(f"{yaml_path}: missing; pass a folder written by rekon run --session")
        text = yaml_path.read_text()
        self.camera = _yaml_map(text, "camera")
        self.volume = _yaml_map(text, "volume")
        self.anchors = {int(r[0]): np.array(r[1:], dtype=float) for r in _rows(self.path / "anchors.txt", 8)}
        self.keyframes = sorted((Keyframe(int(r[0]), int(r[1]), int(r[2]), int(r[3]), int(r[4]), float(r[5]),
                                          np.array(r[6:], dtype=float))
                                 for r in (_rows(p, 13)[0] for p in sorted((self.path / "keyframes").glob("kf_*.txt")))),
                                key=lambda k: k.id)
        frames = _rows(self.path / "frames.txt", 10)
        self.frame_ids = np.array([int(r[0]) for r in frames], dtype=np.int64)
        self.frame_timestamps = np.array([float(r[1]) for r in frames])
        self.frame_anchors = np.array([int(r[2]) for r in frames], dtype=np.int64)
        self.frame_poses_in_anchor = np.array([r[3:] for r in frames], dtype=float).reshape(-1, 7)

    def keyframe_pose(self, keyframe: Keyframe) -> np.ndarray:
        """World pose: its anchor's newest pose times its pose in the anchor."""
        return compose(self.anchors[keyframe.anchor], keyframe.pose_in_anchor)

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """(timestamps, world poses (N, 7)) of every fused frame, by frame id."""
        order = np.argsort(self.frame_ids, kind="stable")
        poses = np.array([compose(self.anchors[a], p)
                          for a, p in zip(self.frame_anchors[order], self.frame_poses_in_anchor[order])])
        return self.frame_timestamps[order], poses.reshape(-1, 7)

    def keyframe_images(self, keyframe_id: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(depth (h, w) float32 metres, weight (h, w) float32, color (h, w, 3) uint8 RGB) of one KF keyframe.
        The header is checked (magic, id, size); the FNV-1a checksum is left to rekon's C++ reader."""
        path = self.path / "keyframes" / f"kf_{keyframe_id:06d}.rks"
        if not path.exists():
            raise SessionError(f"{path}: missing")
        data = path.read_bytes()
        h = np.frombuffer(data, dtype=SPILL_HEADER, count=1)[0] if len(data) >= SPILL_HEADER.itemsize else None
        if h is None or h["magic"] != SPILL_MAGIC or h["id"] != keyframe_id:
            raise SessionError(f"{path}: not keyframe {keyframe_id}'s images (bad header)")
        w, hh = int(h["width"]), int(h["height"])
        pixels = w * hh
        if int(h["payload_bytes"]) != pixels * 11 or len(data) != SPILL_HEADER.itemsize + pixels * 11:
            raise SessionError(f"{path}: {len(data)} bytes, not a {w}x{hh} keyframe's; the file is damaged")
        at = SPILL_HEADER.itemsize
        depth = np.frombuffer(data, "<f4", pixels, at).reshape(hh, w)
        weight = np.frombuffer(data, "<f4", pixels, at + 4 * pixels).reshape(hh, w)
        bgr = np.frombuffer(data, np.uint8, 3 * pixels, at + 8 * pixels).reshape(hh, w, 3)
        return depth, weight, bgr[:, :, ::-1].copy()

    def mesh(self, voxel_size: float | None = None, rekon_binary: str | None = None) -> Mesh:
        """The session's keyframes integrated at their newest poses (`rekon remesh`) as a Mesh."""
        binary = rekon_binary or os.environ.get("REKON_BIN_DIR", str(build_dir() / "bin")) + "/rekon"
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "mesh.ply"
            args = [binary, "remesh", str(self.path), "--out", str(out)]
            if voxel_size:
                args += ["--voxel", str(voxel_size)]
            p = subprocess.run(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            if p.returncode != 0:
                raise SessionError(f"rekon remesh {self.path} failed: {p.stdout.strip().splitlines()[-1:]}")
            return read_ply(out)
