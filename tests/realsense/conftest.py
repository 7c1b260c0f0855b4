"""What the RealSense tests share: where the build is, running a command (in
a private network namespace for anything on the bus: tests/support/in_netns.sh),
and the services' Python package on sys.path for the unit tests."""
import json
import os
import subprocess
import sys

import pytest

SOURCE = os.environ.get("REKON_SOURCE_DIR") or os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
BIN = os.environ.get("REKON_BIN_DIR") or os.path.join(SOURCE, "build", "bin")
BUILD = os.environ.get("REKON_BUILD_DIR") or os.path.dirname(BIN)
IN_NETNS = os.path.join(SOURCE, "tests", "support", "in_netns.sh")

sys.path[:0] = [os.path.join(BUILD, "python"), os.path.join(SOURCE, "services", "realsense")]
os.environ.setdefault("REKON_SOURCE_DIR", SOURCE)


def run(args, timeout=600, env=None, netns=False):
    """(exit code, stdout + stderr) of a command; on the bus only inside a private network namespace."""
    cmd = ([IN_NETNS] if netns else []) + [str(a) for a in args]
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=timeout,
                       env=None if env is None else {**os.environ, **env})
    return p.returncode, p.stdout


def stats(path):
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def error_lines(output):
    return [line for line in output.splitlines() if "error" in line]


def write_bag(dataset, bag, frames=0, streams="depth,color", slowdown=1):
    rc, out = run([os.path.join(BIN, "rekon-realsense-write"), "--dataset", dataset, "--out", bag, "--frames", frames,
                   "--streams", streams, "--slowdown", slowdown], timeout=900)
    assert rc == 0, out
    return out


@pytest.fixture(scope="session")
def tiny_room(tmp_path_factory):
    """A short synthetic room (TUM folder with ground truth and mesh_gt.ply)."""
    d = tmp_path_factory.mktemp("tiny") / "room"
    rc, out = run([os.path.join(BIN, "rekon"), "synth", "--scene", "room", "--frames", 20, "--out", d], timeout=600)
    assert rc == 0, out
    return str(d)
