"""The Python client (python/rekon) against rekon itself: the map followed live in Python is the run's mesh.ply
(python/examples/follow_map.py), a 60-line Python frontend passes `rekon frontend-check`
(python/examples/replay_frontend.py), a Python frame source is received as rekon-player's frames are, a session
folder reads as `rekon export` writes it, and any channel decodes."""

from __future__ import annotations

import collections
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import BIN_DIR, SOURCE_DIR, in_netns, rekon
from rosbag_writer import read_index

from rekon.mesh import Mesh, MeshMap, read_ply
from rekon.poses import read_tum
from rekon.session import Session

PY = sys.executable
EXAMPLES = SOURCE_DIR / "python" / "examples"
# The mapper's quantum (volume.voxel_size 0.01 m / 1024): vertices compare in these steps.
PER_METRE = 1024 / 0.01
URL = "udpm://239.255.76.67:7667?ttl=0"


def triangles_in_quanta(mesh: Mesh) -> collections.Counter:
    """Each triangle as its three vertices in quanta, starting at the smallest (orientation kept): a mesh's surface
    whatever the order and numbering of its vertices."""
    scaled = mesh.vertices.astype(np.float64) * PER_METRE
    q = (np.sign(scaled) * np.floor(np.abs(scaled) + 0.5)).astype(np.int64)
    out = collections.Counter()
    for f in mesh.faces:
        corners = [tuple(q[i]) for i in f]
        k = corners.index(min(corners))
        out[tuple(corners[k:] + corners[:k])] += 1
    return out


@pytest.fixture(scope="module")
def room_run(room, tmp_path_factory) -> Path:
    """`rekon run` on the room with --session, follow_map.py and lcm-logger beside it."""
    d = tmp_path_factory.mktemp("room_run")
    script = (f"{PY} {EXAMPLES}/follow_map.py --out {d}/follow.ply --timeout 240 > {d}/follow.log 2>&1 & f=$!; "
              f"sleep 1; timeout 240 {BIN_DIR}/rekon run --dataset {room} --out {d}/run --session {d}/session "
              f"> {d}/run.log 2>&1; r=$?; wait $f; ff=$?; echo run=$r follow=$ff; [ $r$ff = 00 ]")
    p = in_netns(script, timeout=300)
    assert p.returncode == 0, p.stdout + (d / "run.log").read_text()[-3000:] + (d / "follow.log").read_text()
    return d


def test_the_map_followed_in_python_is_the_runs_mesh(room_run):
    followed, written = read_ply(room_run / "follow.ply"), read_ply(room_run / "run" / "mesh.ply")
    assert len(written.faces) > 10000  # the room: walls, floor and objects
    assert triangles_in_quanta(followed) == triangles_in_quanta(written)
    assert len(followed.faces) == len(written.faces)


def test_a_session_reads_as_rekon_export_writes_it(room_run, tmp_path):
    rekon("export", room_run / "session", "--out", tmp_path / "export")
    session = Session(room_run / "session")
    stamps, poses = session.trajectory()
    ref_stamps, ref_poses = read_tum(tmp_path / "export" / "trajectory.txt")
    assert np.allclose(stamps, ref_stamps, atol=1e-6) and np.allclose(poses, ref_poses, atol=1e-8)
    assert len(session.keyframes) == len(list((room_run / "session" / "keyframes").glob("kf_*.rks")))
    depth, weight, color = session.keyframe_images(session.keyframes[0].id)
    assert depth.shape == (480, 640) and color.shape == (480, 640, 3) and (weight > 0).sum() > 100000
    mesh = session.mesh()
    assert triangles_in_quanta(mesh) == triangles_in_quanta(read_ply(tmp_path / "export" / "mesh.ply"))


def test_the_python_replay_frontend_passes_frontend_check(room, tmp_path):
    d = tmp_path
    seg = f"--set transport.segment=rekon_fr_pyfc_{os.getpid()} --set mapper.store_segment=rekon_kf_pyfc_{os.getpid()}"
    frontend = (f"timeout 120 {BIN_DIR}/rekon-mapper --out {d}/out {seg} > {d}/mapper.log 2>&1 & m=$!; "
                f"{PY} {EXAMPLES}/replay_frontend.py --trajectory {room}/groundtruth.txt --timeout 120 "
                f"> {d}/replay.log 2>&1 & r=$!; timeout 120 {BIN_DIR}/rekon-player --dataset {room} "
                f"--set player.wait_for=[replay,mapper] {seg} > {d}/player.log 2>&1; p=$?; wait $r; rr=$?; "
                f"wait $m; mm=$?; [ $p$rr$mm = 000 ]")
    script = (f"timeout 200 {BIN_DIR}/rekon frontend-check --timeout 150 --ack-name replay > {d}/check.log 2>&1 & "
              f"c=$!; lcm-logger -q \"--lcm-url={URL}\" {d}/run.lcm & g=$!; for i in $(seq 100); do "
              f"grep -q listening {d}/check.log && break; sleep 0.1; done; {frontend}; f=$?; [ $f = 0 ] || kill $c; "
              f"wait $c; cc=$?; kill $g; wait $g; echo frontend=$f check=$cc; [ $f$cc = 00 ]")
    p = in_netns(script, timeout=300)
    logs = "".join(f"\n{n}:\n" + (d / n).read_text()[-2000:] for n in ("check.log", "replay.log", "mapper.log",
                                                                        "player.log") if (d / n).exists())
    assert p.returncode == 0, p.stdout + logs
    check = (d / "check.log").read_text()
    assert check.count("PASS FC") == 11 and "FAIL FC" not in check, check
    assert len(read_ply(d / "out" / "mesh.ply").faces) > 10000  # the mapper fused the frames at the replayed poses
    logged = rekon("frontend-check", "--ack-name", "replay", "--log", d / "run.lcm").stdout
    assert logged.count("PASS FC") == 11, logged


def test_a_python_frame_source_is_received_as_the_players_frames(room, tmp_path):
    """rekon listen prints each frame's id, timestamp and a hash of its pixels: the same lines for the Python
    source's frames (encoded from numpy by rekon.bus) as for rekon-player's (the files, inline)."""
    d = tmp_path
    small = d / "small"
    small.mkdir()
    for name in ("rgb.txt", "depth.txt"):
        (small / name).write_text("\n".join(f"{s} {r}" for s, r in read_index(room / name)[:8]) + "\n")
    for name in ("rgb", "depth", "camera.yaml"):
        (small / name).symlink_to(room / name)
    listen = f"timeout 60 {BIN_DIR}/rekon listen --set transport.mode=lcm --frames-out"
    script = (f"{listen} {d}/python.txt > {d}/l1.log 2>&1 & l=$!; {PY} {Path(__file__).parent}/frame_source.py "
              f"{small} listener > {d}/source.log 2>&1; s=$?; wait $l; ll=$?; "
              f"{listen} {d}/player.txt > {d}/l2.log 2>&1 & l=$!; timeout 60 {BIN_DIR}/rekon-player --dataset {small} "
              f"--set transport.mode=lcm --set player.wait_for=[listener] > {d}/player.log 2>&1; p=$?; wait $l; "
              f"l2=$?; echo source=$s listen=$ll player=$p listen=$l2; [ $s$ll$p$l2 = 0000 ]")
    p = in_netns(script, timeout=200)
    logs = "".join(f"\n{n}:\n" + (d / n).read_text()[-1500:] for n in ("source.log", "l1.log", "player.log", "l2.log"))
    assert p.returncode == 0, p.stdout + logs
    lines = (d / "python.txt").read_text().splitlines()
    assert len(lines) == 8 and lines == (d / "player.txt").read_text().splitlines(), logs


def test_any_channel_decodes_and_a_constraint_goes_out_as_given():
    """In-process (LCM's memq:// bus): an external constraint published from Python comes back decoded."""
    from rekon.bus import Bus

    bus = Bus("memq://")
    got = []
    bus.subscribe(".*", lambda channel, msg: got.append((channel, msg)))
    info = np.diag([1e4, 1e4, 1e4, 1e3, 1e3, 1e3])
    bus.publish_constraint(to_id=8, pose=[1.2, 0.1, 0.9, 0, 0, 0, 1], information=info, source="test", sequence=3)
    bus.publish_frame(5, 1.5, [4, 2, 525, 525, 2, 1], np.arange(8, dtype=np.uint16).reshape(2, 4),
                      np.zeros((2, 4, 3), np.uint8), 5000.0)
    assert bus.run(timeout_s=2, until=lambda: len(got) == 2)
    (c1, constraint), (c2, frame) = got
    assert c1 == "EXTERNAL_CONSTRAINTS" and type(constraint).__name__ == "external_constraint_t"
    assert constraint.kind == constraint.KIND_PRIOR and constraint.to_id == 8 and constraint.sequence == 3
    assert list(constraint.pose.t) == [1.2, 0.1, 0.9] and np.allclose(np.reshape(constraint.information, (6, 6)), info)
    assert constraint.schema_version == bus.schema_version > 0
    assert c2 == "FRAMES" and frame.frame_id == 5 and frame.color_format == "png" and frame.depth_png[:4] == b"\x89PNG"


def test_the_mesh_as_open3d_when_it_is_installed(room_run):
    mesh = read_ply(room_run / "run" / "mesh.ply")
    try:
        import open3d  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="pip install open3d"):
            mesh.to_open3d()
        return
    o3d_mesh = mesh.to_open3d()
    assert len(o3d_mesh.triangles) == len(mesh.faces) and len(o3d_mesh.vertices) == len(mesh.vertices)


def test_a_block_update_replaces_older_versions_and_an_empty_block_removes_it():
    from rekon import msgs
    import zlib

    m = msgs()

    def message(version, vertices, sequence):
        msg = m.mesh_blocks_t()
        msg.sequence, msg.part, msg.parts, msg.full = sequence, 0, 1, False
        msg.voxel_size, msg.block_voxels, msg.quantum = 0.01, 8, 0.01 / 1024
        b = m.mesh_block_t()
        b.bx, b.by, b.bz, b.version, b.cause = 1, 0, 0, version, 0
        b.num_vertices, b.num_triangles = (3, 1) if vertices else (0, 0)
        raw = (np.array([[0, 0, 0], [1024, 0, 0], [0, 1024, 0]], "<u2").tobytes() + bytes(9) +
               np.array([0, 1, 2], "<u2").tobytes()) if vertices else b""
        msg.blocks, msg.num_blocks = [b], 1
        msg.raw_size, msg.payload = len(raw), zlib.compress(raw)
        msg.payload_size = len(msg.payload)
        return msg

    mesh_map = MeshMap()
    assert mesh_map.apply(message(10, True, 0)) == 1
    mesh = mesh_map.to_mesh()
    # Block (1, 0, 0) starts at 8 voxels * 1 cm = 0.08 m; vertex 1 is one voxel (1024 quanta) further along x.
    assert np.allclose(mesh.vertices[1], [0.09, 0, 0]) and mesh.faces.tolist() == [[0, 1, 2]]
    assert mesh_map.apply(message(5, False, 1)) == 0  # an older version changes nothing
    assert mesh_map.apply(message(12, False, 2)) == 1 and len(mesh_map.to_mesh().faces) == 0
