"""rekon-realsense on the bus has the C++ services' lifecycle: heartbeats from
starting to exited, live STATS and the whole stats.json as its last STATS, a
SHUTDOWN message ending it cleanly mid-stream, and frames the C++ consumers'
frame_t decoding accepts (listened to by bus_listener.py in a private network
namespace)."""
import json
import os
import sys

import pytest

from conftest import BIN, BUILD, run, stats, write_bag

HERE = os.path.dirname(os.path.abspath(__file__))


@pytest.fixture(scope="module")
def slow_bag(tiny_room, tmp_path_factory):
    """The 20-frame room at 10 Hz (2 s): long enough to stop it mid-stream."""
    bag = str(tmp_path_factory.mktemp("lifecycle") / "room.bag")
    write_bag(tiny_room, bag, slowdown=3)
    return bag


def listen(out, bag, shutdown_after=0):
    rc, text = run([sys.executable, os.path.join(HERE, "bus_listener.py"), "--shutdown-after", shutdown_after, "--",
                    os.path.join(BIN, "rekon-realsense"), "--playback", bag, "--out", out, "--set",
                    "realsense.wait_for=[]", "--set", "realsense.fps=10"], netns=True,
                   env={"PYTHONPATH": os.path.join(BUILD, "python")})
    assert rc == 0, text
    return json.loads(text.strip().splitlines()[-1])


def test_heartbeats_go_from_starting_to_exited_and_the_last_stats_are_the_file(slow_bag, tmp_path):
    seen = listen(tmp_path, slow_bag)
    assert seen["rc"] == 0, seen["log"]
    assert seen["states"][0] == "starting" and "capturing" in seen["states"], seen["states"]
    # After its end of stream it lingers until its consumers are finished (none
    # here); its last heartbeat says it handles nothing more, as a C++ service's.
    assert seen["states"][-2:] == ["lingering", "exited"], seen["states"]
    final = stats(tmp_path / "realsense_stats.json")
    assert seen["stats"][-1] == final  # the whole stats.json, published at exit
    assert any("frames_captured" in s and "peak_rss_mb" not in s for s in seen["stats"])  # live numbers before
    assert final["frames_sent"] == len(seen["frames"]) == 19  # 20 recorded, the syncer's first one apart


def test_every_frame_is_a_frame_t_the_consumers_decode(slow_bag, tmp_path):
    seen = listen(tmp_path, slow_bag)
    frames = seen["frames"]
    with open(tmp_path / "camera.yaml") as f:
        k = {key: float(v) for key, v in (line.split(":") for line in f)}
    assert [f["id"] for f in frames] == list(range(len(frames)))
    for f in frames:
        assert f["schema"] and (f["w"], f["h"]) == (640, 480) and f["fx"] == k["fx"]
        assert f["depth_scale"] == pytest.approx(k["depth_scale"])
        # P5 16-bit depth and P6 color, headers included: rekon's image_io reads both.
        assert f["depth_bytes"] == 640 * 480 * 2 + len(b"P5\n640 480\n65535\n")
        assert f["color_bytes"] == 640 * 480 * 3 + len(b"P6\n640 480\n255\n") and f["color_format"] == "ppm"
    stamps = [f["t"] for f in frames]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))


def test_a_shutdown_message_mid_stream_ends_it_cleanly_with_its_stats(slow_bag, tmp_path):
    seen = listen(tmp_path, slow_bag, shutdown_after=5)
    assert seen["rc"] == 0, seen["log"]
    assert "shutdown requested (interrupted)" in seen["log"]
    s = stats(tmp_path / "realsense_stats.json")
    assert 5 <= s["frames_sent"] < 19  # stopped at about 5 of the 2 s recording's 19
    assert s["end"] == "end of stream"
    assert seen["states"][-1] == "exited"
