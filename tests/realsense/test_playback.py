"""The synthetic room recorded by Intel's SDK into a .bag (rekon-realsense-write:
rs.software_device + rs.recorder), played back by the SDK at its recorded rate
through `rekon run --camera realsense --playback`, against the same frames
read as a TUM folder by `rekon run --dataset`. REKON_REALSENSE_FRAMES sets the
length and REKON_REALSENSE_SLOWDOWN the recording's rate (30 Hz / it): 150
frames at 15 Hz for CI, where other jobs share the 2 cores (as the freenect
tests play at 15 Hz); the issue's goal is 600 at 30 Hz (FRAMES=600
SLOWDOWN=1: services/realsense/README.md has the numbers)."""
import json
import os

import numpy as np
import pytest
import yaml
from PIL import Image

from conftest import BIN, run, stats, write_bag
from rekon_realsense.ground_truth import live_ground_truth as live_ground_truth_file

FRAMES = int(os.environ.get("REKON_REALSENSE_FRAMES", "150"))
SLOWDOWN = int(os.environ.get("REKON_REALSENSE_SLOWDOWN", "2"))
FPS = 30 // SLOWDOWN
REKON = os.path.join(BIN, "rekon")


def tum_index(path):
    out = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            p = line.split()
            if p and not line.startswith("#"):
                out.append((float(p[0]), p[1:]))
    return out


def camera_yaml(folder):
    with open(os.path.join(folder, "camera.yaml"), encoding="utf-8") as f:
        return {k.strip(): float(v) for k, v in (line.split("#")[0].split(":") for line in f if ":" in line)}


def eval_json(args):
    rc, text = run([REKON, "eval"] + args + ["--json"])
    assert rc == 0, text
    return json.loads(text[text.index("{"):])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("playback")
    room, bag = d / "room", str(d / "room.bag")
    rc, text = run([REKON, "synth", "--scene", "room", "--frames", FRAMES, "--out", room], timeout=900)
    assert rc == 0, text
    print(write_bag(room, bag, slowdown=SLOWDOWN))
    rc, text = run([REKON, "run", "--dataset", room, "--out", d / "files"], netns=True, timeout=900)
    assert rc == 0, text
    rc, text = run([REKON, "run", "--camera", "realsense", "--playback", bag, "--record", d / "recorded", "--out",
                    d / "rs", "--set", f"realsense.fps={FPS}"], netns=True, timeout=900)
    assert rc == 0, text + open(d / "rs" / "realsense.log").read()
    return {"room": str(room), "files": str(d / "files"), "rs": str(d / "rs"), "recorded": str(d / "recorded"),
            "dir": d, "source": stats(d / "rs" / "realsense_stats.json"), "run": stats(d / "rs" / "stats.json")}


def frames_csv(rs):
    rows = np.loadtxt(os.path.join(rs, "realsense_frames.csv"), delimiter=",", skiprows=1, ndmin=2)
    return rows[:, 0].astype(int), rows[:, 1].astype(int), rows[:, 2], rows[:, 3]


def live_ground_truth(r):
    """The room's ground-truth pose of each frame the source took, at the host
    stamp it carried (rekon-realsense-gt's work: the bag's frame number is the
    dataset index + 1, and its device time the dataset time, checked)."""
    path = os.path.join(str(r["dir"]), "live_gt.txt")
    # One row per frame taken (frames_captured: those sent and those dropped).
    assert live_ground_truth_file(r["room"], os.path.join(r["rs"], "realsense_frames.csv"), path, SLOWDOWN) == \
        r["source"]["frames_captured"]
    return path


def test_at_the_recorded_rate_at_most_one_percent_of_the_frames_is_skipped(runs):
    s = runs["source"]
    print(json.dumps(s, indent=1))
    # Every recorded frame is taken or counted: skipped late (the SDK dropped
    # it before the capture loop took it). The one frame short: the SDK's
    # pipeline passes complete framesets only, and the first depth frame of a
    # playback comes before its syncer has seen a color frame.
    assert s["frames_captured"] + s["frames_skipped_late"] == FRAMES - 1
    assert s["frames_skipped_late"] <= 0.01 * FRAMES
    # The consumers keep up on 2 cores: what they were not ready for is
    # dropped (at 30 Hz with other builds on the machine: 0-1.2 %).
    assert s["frames_sent"] >= 0.95 * FRAMES
    # At the recorded rate: the frames span what they were recorded over.
    assert s["sequence_seconds"] == pytest.approx(FRAMES / FPS, rel=0.05)


def test_every_frame_sent_is_tracked(runs):
    tracker = runs["run"]["tracker"]
    assert tracker["frames"] == runs["source"]["frames_sent"]
    assert tracker["lost_frames"] == 0


def test_on_one_host_the_frames_go_through_the_shared_memory_ring_and_it_is_removed(runs):
    # transport.mode auto, every consumer on this host: the C++ consumers read
    # the Python source's ring (every frame sent was tracked, above), and
    # nothing of it is left once the run is over.
    assert runs["source"]["transport"] == "shm"
    segment = yaml.safe_load(open(os.path.join(runs["rs"], "config.yaml")))["transport"]["segment"]
    assert not os.path.exists(os.path.join("/dev/shm", segment))


def test_the_trajectory_is_within_1_2x_of_the_file_runs(runs):
    files = eval_json(["traj", os.path.join(runs["room"], "groundtruth.txt"),
                       os.path.join(runs["files"], "trajectory.txt")])
    live = eval_json(["traj", live_ground_truth(runs), os.path.join(runs["rs"], "trajectory.txt")])
    print(f"ATE files {files['ate_rmse_m'] * 1e3:.3f} mm, realsense playback {live['ate_rmse_m'] * 1e3:.3f} mm")
    assert live["matched"] == runs["source"]["frames_sent"]
    assert live["ate_rmse_m"] <= 1.2 * files["ate_rmse_m"]


def test_the_mesh_is_within_1_mm_of_the_file_runs(runs):
    ref = os.path.join(runs["room"], "mesh_gt.ply")
    files = eval_json(["surface", os.path.join(runs["files"], "mesh.ply"), ref, "--est-trajectory",
                       os.path.join(runs["files"], "trajectory.txt"), "--gt-trajectory",
                       os.path.join(runs["room"], "groundtruth.txt")])
    live = eval_json(["surface", os.path.join(runs["rs"], "mesh.ply"), ref, "--est-trajectory",
                      os.path.join(runs["rs"], "trajectory.txt"), "--gt-trajectory", live_ground_truth(runs)])
    print(f"CORR files {files['corr_m'] * 1e3:.3f} mm, realsense playback {live['corr_m'] * 1e3:.3f} mm")
    assert abs(live["corr_m"] - files["corr_m"]) <= 0.001


def test_the_devices_identity_mode_and_timestamps_are_in_its_stats(runs):
    s = runs["source"]
    assert s["serial"] == "REKONSYNTH"
    assert s["mode"] == f"640x480@{FPS} depth z16 aligned to color rgb8"
    # The room's camera.yaml depth_scale (values per metre), through the bag's depth units (a float32).
    assert s["depth_units_m"] == pytest.approx(1.0 / camera_yaml(runs["room"])["depth_scale"], rel=1e-6)
    assert s["timestamp_domain"] == "hardware_clock"
    assert s["end"] == "end of stream"
    # The frames carry the device's spacing (33.3 ms times the slowdown) on the host clock, not
    # their arrival jitter, once the clock's envelope has met the least
    # delayed arrival (the first frames of a start-up arrive late).
    _, _, device_ms, stamps = frames_csv(runs["rs"])
    assert np.max(np.abs(np.diff(stamps[10:]) - np.diff(device_ms[10:]) / 1e3)) < 0.001


def test_the_recording_holds_every_captured_frame_as_the_room_had_it(runs):
    s = runs["source"]
    assert s["frames_recorded"] == s["frames_captured"] and s["record_dropped"] == 0 and s["record_failed"] == 0
    rec = runs["recorded"]
    with open(os.path.join(rec, "camera.yaml")) as a, open(os.path.join(runs["rs"], "camera.yaml")) as b:
        assert a.read() == b.read()
    room_k, rec_k = camera_yaml(runs["room"]), camera_yaml(rec)
    for key in ("width", "height", "fx", "fy", "cx", "cy"):  # read from the recording by the SDK
        assert rec_k[key] == pytest.approx(room_k[key], rel=1e-6)
    # Frames 0, middle, last: color bit-exact; depth after the SDK's align
    # (identity extrinsics, equal intrinsics) equal on nearly every pixel.
    rgb_src, depth_src = tum_index(os.path.join(runs["room"], "rgb.txt")), tum_index(
        os.path.join(runs["room"], "depth.txt"))
    rgb_rec, depth_rec = tum_index(os.path.join(rec, "rgb.txt")), tum_index(os.path.join(rec, "depth.txt"))
    _, numbers, _, _ = frames_csv(runs["rs"])
    assert len(rgb_rec) == s["frames_recorded"]
    for i in (0, len(rgb_rec) // 2, len(rgb_rec) - 1):
        n = numbers[i] - 1
        src_c = np.array(Image.open(os.path.join(runs["room"], rgb_src[n][1][0])).convert("RGB"))
        rec_c = np.array(Image.open(os.path.join(rec, rgb_rec[i][1][0])))
        assert np.array_equal(src_c, rec_c)
        src_d = np.array(Image.open(os.path.join(runs["room"], depth_src[n][1][0]))).astype(np.int64)
        rec_d = np.array(Image.open(os.path.join(rec, depth_rec[i][1][0]))).astype(np.int64)
        same = np.mean(src_d == rec_d)
        print(f"frame {i}: depth equal on {same * 100:.2f} % of the pixels")
        assert same > 0.99
