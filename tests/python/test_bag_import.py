"""`rekon import bag`: synthetic frames written by the test as a ROS 1 bag, a ROS 2 sqlite3 bag and a ROS 2 mcap bag
are imported into byte-identical depth and color PNGs, the timestamps and the camera of the TUM folder they came from, and a run on the
import gives the same trajectory; TUM's fr3/teddy as a ROS 1 bag with TUM's own topics and encodings runs as the
folder does; bad input is one line naming the topic and the fix."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA, ate, rekon, run_pipeline
from rosbag_writer import png_pixels, read_camera, read_index, write_dataset_bag

TEDDY = SHARED_DATA / "tum_fr3_teddy_200"


def millimetre_copy(room: Path, out: Path) -> Path:
    """The room with its depth in millimetres (depth_scale 1000), the unit of 16UC1 depth (REP 118)."""
    (out / "depth").mkdir(parents=True)
    shutil.copytree(room / "rgb", out / "rgb")
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        shutil.copy(room / name, out / name)
    cam = read_camera(room / "camera.yaml")
    for _, rel in read_index(room / "depth.txt"):
        d = png_pixels(room / rel).astype(np.float64) * (1000.0 / cam["depth_scale"])
        from rekon.bag import write_png

        write_png(out / rel, np.rint(d).astype(np.uint16))
    (out / "camera.yaml").write_text("".join(f"{k}: {cam[k]:g}\n" for k in ("width", "height", "fx", "fy", "cx", "cy"))
                                     + "depth_scale: 1000\n")
    return out


@pytest.fixture(scope="module")
def room_mm(room, tmp_path_factory) -> Path:
    return millimetre_copy(room, tmp_path_factory.mktemp("room_mm") / "room_mm")


def expect_same_dataset(imported: Path, reference: Path):
    """Same timestamps, byte-identical depth and color files (rekon.png encodes as rekon synth does), same camera."""
    ref_depth, ref_rgb = read_index(reference / "depth.txt"), read_index(reference / "rgb.txt")
    got_depth, got_rgb = read_index(imported / "depth.txt"), read_index(imported / "rgb.txt")
    assert [s for s, _ in got_depth] == [s for s, _ in ref_depth]
    assert [s for s, _ in got_rgb] == [s for s, _ in ref_rgb]
    for (_, g), (_, r) in list(zip(got_depth, ref_depth)) + list(zip(got_rgb, ref_rgb)):
        assert (imported / g).read_bytes() == (reference / r).read_bytes(), f"{g} differs from {r}"
    assert read_camera(imported / "camera.yaml") == read_camera(reference / "camera.yaml")


# Each bag kind with another pair of encodings: 32FC1 metres (scale 5000 back exactly: float32 keeps 24 bits),
# 16UC1 millimetres, and color as rgb8, bgr8 and a CompressedImage holding the folder's own PNG bytes.
CASES = {
    "ros1": ("32FC1", "rgb8", "room"),
    "sqlite3": ("16UC1", "bgr8", "room_mm"),
    "mcap": ("16UC1", "png", "room_mm"),
}


# Two runs on the same frames agree to this (metres, and quaternion components). Without a loop closure they are
# byte-identical (120 frames of the room); with them, background loop checks and time-capped optimisations depend
# on timing (docs/recording.md, "Determinism"): on all 600 frames of the room (4 loop closures) the runs on the three
# imports and on their folders differed by 1, 16 and 157 nanometres at most.
SAME_POSE = 1e-6


def expect_same_trajectory(got: str, expected: str):
    rows = [[np.array(line.split(), dtype=float) for line in text.splitlines() if line and not line.startswith("#")]
            for text in (got, expected)]
    a, b = (np.array(r) for r in rows)
    assert a.shape == b.shape and a.shape[0] > 0, f"{a.shape} poses against {b.shape}"
    assert np.array_equal(a[:, 0], b[:, 0]), "the runs tracked other frames"
    worst = np.abs(a[:, 1:] - b[:, 1:]).max()
    print(f"trajectories: {len(a)} poses, {'identical' if got == expected else f'largest difference {worst:.3g}'}")
    assert worst <= SAME_POSE


FOLDER_RUNS: dict[Path, str] = {}  # trajectory.txt of a run on each reference folder, made once


@pytest.mark.parametrize("kind", list(CASES))
def test_a_bag_of_the_room_imports_into_the_same_files_and_runs_into_the_same_trajectory(kind, request, tmp_path):
    depth_encoding, color_encoding, reference_name = CASES[kind]
    reference = request.getfixturevalue(reference_name)
    bag = tmp_path / ("room.bag" if kind == "ros1" else "room_bag")
    write_dataset_bag(reference, bag, kind, depth_encoding=depth_encoding, color_encoding=color_encoding)
    out = rekon("import", "bag", bag, "--out", tmp_path / "imported").stdout
    shutil.rmtree(bag) if bag.is_dir() else bag.unlink()
    frames = len(read_index(reference / "rgb.txt"))
    assert f"import: {frames} frames" in out, out
    assert "dropped 0 of" in out, out
    expect_same_dataset(tmp_path / "imported", reference)
    # The run on the import and on the folder: the same frames make the same trajectory.
    if reference not in FOLDER_RUNS:
        FOLDER_RUNS[reference] = run_pipeline(reference, tmp_path / "run_folder")
    expect_same_trajectory(run_pipeline(tmp_path / "imported", tmp_path / "run_imported"), FOLDER_RUNS[reference])


def test_tum_teddy_as_a_ros1_bag_with_tum_topics_runs_as_the_folder_does(tmp_path):
    if not TEDDY.is_dir():
        pytest.skip(f"{TEDDY} is not here (REKON_SHARED_DATA)")
    bag = tmp_path / "rgbd_dataset_freiburg3_teddy.bag"
    write_dataset_bag(TEDDY, bag, "ros1", depth_encoding="32FC1", color_encoding="rgb8", groundtruth="/tf")
    listed = rekon("import", "bag", bag, "--list").stdout
    for line in ("/camera/depth/image", "sensor_msgs/msg/Image", "200 msgs", "32FC1 640x480",
                 "/camera/rgb/image_color", "rgb8 640x480", "/camera/rgb/camera_info", "/tf", "8080 msgs"):
        assert line in listed, listed
    out = rekon("import", "bag", bag, "--out", tmp_path / "teddy", "--groundtruth", "/tf",
                "--gt-frames", "/world", "/kinect").stdout
    bag.unlink()
    # TUM's associate pairs 193 of the 200 (the folder's SOURCE.txt): 7 depth and 7 color images have no partner.
    assert "import: 193 frames" in out and "dropped 7 of 200 depth and 7 of 200 color" in out, out
    # /tf's world -> kinect transforms are TUM's groundtruth.txt, line for line.
    assert np.array_equal(np.loadtxt(tmp_path / "teddy" / "groundtruth.txt"), np.loadtxt(TEDDY / "groundtruth.txt"))
    run_pipeline(tmp_path / "teddy", tmp_path / "run_bag")
    run_pipeline(TEDDY, tmp_path / "run_folder")
    ate_bag = ate(tmp_path / "teddy" / "groundtruth.txt", tmp_path / "run_bag" / "trajectory.txt")
    ate_folder = ate(TEDDY / "groundtruth.txt", tmp_path / "run_folder" / "trajectory.txt")
    print(f"teddy ATE: bag {ate_bag * 1000:.2f} mm, folder {ate_folder * 1000:.2f} mm")
    assert abs(ate_bag - ate_folder) <= 0.02 * ate_folder


@pytest.fixture(scope="module")
def small(room, tmp_path_factory) -> Path:
    """Five frames of the room: enough for the bad-input cases."""
    out = tmp_path_factory.mktemp("small") / "small"
    out.mkdir()
    for name in ("rgb.txt", "depth.txt"):
        (out / name).write_text("\n".join(f"{s} {r}" for s, r in read_index(room / name)[:5]) + "\n")
    for folder in ("rgb", "depth"):
        (out / folder).symlink_to(room / folder)
    shutil.copy(room / "camera.yaml", out / "camera.yaml")
    (out / "groundtruth.txt").symlink_to(room / "groundtruth.txt")
    return out


def test_ground_truth_from_a_pose_stamped_topic_is_the_folders(small, tmp_path):
    bag = tmp_path / "gt"
    write_dataset_bag(small, bag, "mcap", depth_encoding="16UC1", color_encoding="png", groundtruth="/mocap/pose",
                      gt_type="pose")
    rekon("import", "bag", bag, "--out", tmp_path / "out", "--groundtruth", "/mocap/pose")
    got = np.loadtxt(tmp_path / "out" / "groundtruth.txt")
    expected = np.loadtxt(small / "groundtruth.txt")
    assert got.shape == expected.shape and np.allclose(got, expected, rtol=0, atol=1e-9)


def test_mono8_color_becomes_a_grey_png(small, tmp_path):
    bag = tmp_path / "mono.bag"
    write_dataset_bag(small, bag, "ros1", depth_encoding="32FC1", color_encoding="mono8")
    rekon("import", "bag", bag, "--out", tmp_path / "out")
    (_, got), (_, source) = read_index(tmp_path / "out" / "rgb.txt")[0], read_index(small / "rgb.txt")[0]
    grey = png_pixels(tmp_path / "out" / got)
    assert grey.dtype == np.uint8 and grey.ndim == 2  # the writer sends the red channel as mono8
    assert np.array_equal(grey, png_pixels(small / source)[:, :, 0])


def one_error_line(p) -> str:
    lines = [line for line in p.stdout.splitlines() if line.strip()]
    assert p.returncode == 1, p.stdout
    assert len(lines) == 1 and lines[0].startswith("rekon import bag: error: "), p.stdout
    return lines[0]


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_a_truncated_bag_is_one_line_naming_the_bag_and_the_fix(kind, small, tmp_path):
    bag = tmp_path / ("cut.bag" if kind == "ros1" else "cut")
    write_dataset_bag(small, bag, kind, depth_encoding="32FC1", color_encoding="rgb8")
    data_file = bag if kind == "ros1" else next(bag.glob("*.mcap"))
    data = data_file.read_bytes()
    data_file.write_bytes(data[: len(data) // 2])  # a recording killed half way
    line = one_error_line(rekon("import", "bag", bag, "--out", tmp_path / "out", check=False))
    assert str(bag) in line and "reindex" in line, line
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.importing").exists()


def test_a_color_topic_without_camera_info_is_one_line_naming_the_topic_and_the_fix(small, tmp_path):
    bag = tmp_path / "noinfo.bag"
    write_dataset_bag(small, bag, "ros1", depth_encoding="32FC1", color_encoding="rgb8", info_topic=None)
    line = one_error_line(rekon("import", "bag", bag, "--out", tmp_path / "out", check=False))
    assert "/camera/rgb/image_color has no CameraInfo" in line and "--camera-info" in line and "--intrinsics" in line
    # The fix works: the intrinsics given on the command line.
    rekon("import", "bag", bag, "--out", tmp_path / "out", "--intrinsics", "525", "525", "319.5", "239.5")
    assert read_camera(tmp_path / "out" / "camera.yaml")["fx"] == 525


def test_an_unknown_color_encoding_is_one_line_naming_the_topic_and_the_fix(small, tmp_path):
    bag = tmp_path / "yuv"
    write_dataset_bag(small, bag, "sqlite3", depth_encoding="16UC1", color_encoding="rgb8", color_label="yuv422")
    line = one_error_line(rekon("import", "bag", bag, "--out", tmp_path / "out", check=False))
    assert "/camera/rgb/image_color: color encoding 'yuv422' is not supported" in line and "rgb8" in line, line
    assert not (tmp_path / "out").exists()


def test_several_depth_topics_ask_for_one_by_name(small, tmp_path):
    bag = tmp_path / "two.bag"
    from rosbag_writer import BagWriter

    w = BagWriter(bag, "ros1")
    for topic in ("/a/depth", "/b/depth"):
        w.add(topic, "sensor_msgs/msg/Image")
        w.write(topic, w.image("1.000000", "f", np.zeros((4, 4), np.uint16), "16UC1"), 1_000_000_000)
    w.close()
    line = one_error_line(rekon("import", "bag", bag, "--out", tmp_path / "out", check=False))
    assert "several depth image" in line and "/a/depth, /b/depth" in line and "--depth-topic" in line, line
