"""What the Python tests share: where the build, the data and the sources are (set by ctest through
rekon_add_pytest), running rekon's commands, and the synthetic room written once per test file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SOURCE_DIR = Path(os.environ.get("REKON_SOURCE_DIR", Path(__file__).resolve().parents[2]))
BUILD_DIR = Path(os.environ.get("REKON_BUILD_DIR", SOURCE_DIR / "build"))
BIN_DIR = Path(os.environ.get("REKON_BIN_DIR", BUILD_DIR / "bin"))
SHARED_DATA = Path(os.environ.get("REKON_SHARED_DATA", SOURCE_DIR.parent / "shared" / "data"))
IN_NETNS = SOURCE_DIR / "tests" / "support" / "in_netns.sh"

# The package under test and the generated types, as `rekon import` finds them.
sys.path[:0] = [str(SOURCE_DIR / "python"), str(BUILD_DIR / "python"), str(Path(__file__).parent)]
os.environ["PYTHONPATH"] = os.pathsep.join([str(SOURCE_DIR / "python"), str(BUILD_DIR / "python"),
                                            os.environ.get("PYTHONPATH", "")])


def rekon(*args, timeout=300, check=True) -> subprocess.CompletedProcess:
    """build/bin/rekon ARGS; stdout and stderr together in .stdout."""
    p = subprocess.run([str(BIN_DIR / "rekon"), *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                       text=True, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"rekon {' '.join(map(str, args))} exited {p.returncode}:\n{p.stdout[-4000:]}")
    return p


def in_netns(script: str, timeout=300) -> subprocess.CompletedProcess:
    """A bash script in a private network namespace (LCM multicast on loopback only)."""
    return subprocess.run([str(IN_NETNS), "bash", "-c", script], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, timeout=timeout)


def run_pipeline(dataset: Path, out: Path, *extra, timeout=300) -> str:
    """`rekon run --dataset DATASET --out OUT` in its own network namespace; its trajectory.txt's text."""
    p = in_netns(f"timeout {timeout - 10} {BIN_DIR}/rekon run --dataset {dataset} --out {out} "
                 + " ".join(map(str, extra)), timeout=timeout)
    assert p.returncode == 0, p.stdout[-4000:]
    return (out / "trajectory.txt").read_text()


def ate(groundtruth: Path, trajectory: Path) -> float:
    out = rekon("eval", "traj", groundtruth, trajectory).stdout
    return float(out.split("ate_rmse_m=")[1].split()[0])


def evo_ape(groundtruth: Path, trajectory: Path) -> float:
    """evo's APE RMSE (translation, after an SE(3) alignment) of a TUM trajectory against ground truth."""
    evo = SOURCE_DIR / ".venv" / "bin" / "evo_ape"
    p = subprocess.run([str(evo), "tum", str(groundtruth), str(trajectory), "--align"], stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True, timeout=120, env={**os.environ, "MPLBACKEND": "Agg"})
    assert p.returncode == 0, p.stdout
    for line in p.stdout.splitlines():
        if line.strip().startswith("rmse"):
            return float(line.split()[1])
    raise AssertionError(f"no rmse line in evo_ape's output:\n{p.stdout}")


@pytest.fixture(scope="session")
def room(tmp_path_factory) -> Path:
    """The synthetic room (exact ground truth), ROOM_FRAMES frames."""
    out = tmp_path_factory.mktemp("room") / "room"
    rekon("synth", "--scene", "room", "--frames", ROOM_FRAMES, "--out", out, timeout=600)
    return out


# The room's frames in the tests: 120 keep CI short (4 s of the 20 s loop); REKON_ROOM_FRAMES=600 for all of it.
ROOM_FRAMES = int(os.environ.get("REKON_ROOM_FRAMES", "120"))
