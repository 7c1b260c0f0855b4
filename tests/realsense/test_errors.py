"""Bad input to rekon-realsense: each is one line naming the thing and the fix,
a non-zero exit, and nothing half-written; through `rekon run`, refused before
anything starts (rekon-realsense --check), and `rekon cameras` asks the SDK. Recordings are made here by the SDK
(rekon-realsense-write) from a 20-frame synthetic room."""
import os
import subprocess
import sys

import pytest

from conftest import BIN, error_lines, run, write_bag

REALSENSE = os.path.join(BIN, "rekon-realsense")
NO_CONSUMERS = ["--set", "realsense.wait_for=[]"]


def one_error_line(output):
    lines = error_lines(output)
    assert len(lines) == 1, output
    return lines[0]


@pytest.fixture(scope="module")
def room_bag(tiny_room, tmp_path_factory):
    bag = str(tmp_path_factory.mktemp("bags") / "room.bag")
    write_bag(tiny_room, bag, frames=10)
    return bag


def test_a_missing_recording_is_refused_before_anything_starts(tmp_path):
    out = tmp_path / "run"
    rc, text = run([os.path.join(BIN, "rekon"), "run", "--camera", "realsense", "--playback", tmp_path / "none.bag",
                    "--out", out], netns=True)
    assert rc != 0
    line = one_error_line(text)
    assert "none.bag" in line and "no such RealSense recording" in line
    assert not out.exists()  # refused before the run folder was made


def test_the_service_itself_names_a_missing_recording(tmp_path):
    rc, text = run([REALSENSE, "--playback", tmp_path / "none.bag", "--out", tmp_path / "o"] + NO_CONSUMERS,
                   netns=True)
    assert rc == 1
    assert "none.bag: no such RealSense recording" in one_error_line(text)


def test_a_file_that_is_no_bag_is_one_line(tmp_path):
    bad = tmp_path / "notes.bag"
    bad.write_text("not a rosbag\n")
    rc, text = run([REALSENSE, "--playback", bad, "--out", tmp_path / "o"] + NO_CONSUMERS, netns=True)
    assert rc == 1
    assert "not a readable RealSense .bag recording" in one_error_line(text)


def test_a_recording_without_depth_is_one_line(tiny_room, tmp_path):
    bag = str(tmp_path / "color_only.bag")
    write_bag(tiny_room, bag, frames=5, streams="color")
    rc, text = run([REALSENSE, "--playback", bag, "--out", tmp_path / "o"] + NO_CONSUMERS, netns=True)
    assert rc == 1
    assert "has no depth stream (it holds color 640x480@30 rgb8)" in one_error_line(text)
    # Its stats are still written, saying nothing was sent.
    assert os.path.exists(tmp_path / "o" / "realsense_stats.json")


def test_a_recording_without_depth_through_rekon_run_is_refused_before_anything_starts(tiny_room, tmp_path):
    bag = str(tmp_path / "color_only.bag")
    write_bag(tiny_room, bag, frames=5, streams="color")
    out = tmp_path / "run"
    rc, text = run([os.path.join(BIN, "rekon"), "run", "--camera", "realsense", "--playback", bag, "--out", out],
                   netns=True, timeout=300)
    assert rc == 1
    line = one_error_line(text)
    assert line.startswith("rekon run: error: --camera realsense: " + bag + ": the recording has no depth stream")
    assert not out.exists()  # refused by rekon-realsense --check before the run folder was made


def test_a_mode_the_recording_does_not_hold_through_rekon_run_is_refused_before_anything_starts(room_bag, tmp_path):
    out = tmp_path / "run"
    rc, text = run([os.path.join(BIN, "rekon"), "run", "--camera", "realsense", "--playback", room_bag, "--out", out,
                    "--set", "realsense.fps=15"], netns=True)
    assert rc == 1
    assert "mode 640x480@15 is not in the recording" in one_error_line(text)
    assert not out.exists()


def test_no_camera_through_rekon_run_is_refused_before_anything_starts(tmp_path):
    # No RealSense exists on the machines that run these tests.
    out = tmp_path / "run"
    rc, text = run([os.path.join(BIN, "rekon"), "run", "--camera", "realsense", "--out", out], netns=True)
    assert rc == 1
    assert one_error_line(text).startswith("rekon run: error: --camera realsense: no RealSense camera found: plug a "
                                           "D4xx into a USB 3 port")
    assert not out.exists()


def test_rekon_cameras_asks_the_sdk_and_finds_no_realsense_here():
    rc, text = run([os.path.join(BIN, "rekon"), "cameras"])
    assert rc == 1 and "RealSense cameras not listed" not in text  # the SDK answered: none connected
    assert "no camera found" in text and "realsense --playback FILE.bag" in text


def test_a_mode_the_recording_does_not_hold_is_one_line(room_bag, tmp_path):
    rc, text = run([REALSENSE, "--playback", room_bag, "--out", tmp_path / "o", "--set", "realsense.width=1280"]
                   + NO_CONSUMERS, netns=True)
    assert rc == 1
    line = one_error_line(text)
    assert "mode 1280x480@30 is not in the recording" in line and "depth 640x480@30 z16" in line


@pytest.fixture(scope="module")
def venv_without_sdk(tmp_path_factory):
    """A Python environment holding every package of the project's but
    pyrealsense2: a bare venv whose .pth points at links to the others."""
    tmp_path = tmp_path_factory.mktemp("nosdk")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", venv], check=True)
    site = next(p for p in sys.path if p.endswith("site-packages") and os.path.isdir(p))
    others = tmp_path / "others"
    others.mkdir()
    for name in os.listdir(site):
        if not name.startswith("pyrealsense2"):
            os.symlink(os.path.join(site, name), others / name)
    venv_site = next((venv / "lib").glob("python3*/site-packages"))
    (venv_site / "others.pth").write_text(str(others) + "\n")
    return str(venv)


def missing_sdk(venv):
    return ("missing Python packages in " + venv + ": pyrealsense2 (Intel's RealSense SDK); run tools/rekon deps (it "
            "installs python/requirements.txt from PyPI)")


def test_without_the_sdk_it_says_so_in_one_line(venv_without_sdk, tmp_path):
    rc, text = run([REALSENSE, "--out", tmp_path / "o"] + NO_CONSUMERS, env={"REKON_VENV": venv_without_sdk},
                   netns=True)
    assert rc == 1
    assert one_error_line(text).endswith(missing_sdk(venv_without_sdk))


def test_without_the_sdk_rekon_run_is_refused_before_anything_starts_and_cameras_says_why(venv_without_sdk, tmp_path):
    out = tmp_path / "run"
    rc, text = run([os.path.join(BIN, "rekon"), "run", "--camera", "realsense", "--out", out],
                   env={"REKON_VENV": venv_without_sdk}, netns=True)
    assert rc == 1
    assert one_error_line(text) == "rekon run: error: --camera realsense: " + missing_sdk(venv_without_sdk)
    assert not out.exists()
    rc, text = run([os.path.join(BIN, "rekon"), "cameras"], env={"REKON_VENV": venv_without_sdk})
    assert rc == 1
    assert "RealSense cameras not listed: " + missing_sdk(venv_without_sdk) in text.splitlines()


def test_no_camera_connected_is_one_line(tmp_path):
    # No RealSense exists on the machines that run these tests.
    rc, text = run([REALSENSE, "--out", tmp_path / "o"] + NO_CONSUMERS, netns=True)
    assert rc == 1
    assert "no RealSense camera found" in one_error_line(text)
