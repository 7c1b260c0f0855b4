"""lcm-spy decodes rekon's channels: the build's rekon_msgs.jar (lcm-gen -j, javac), found by lcm-spy's own type
lookup, decodes every event of an lcm-logger log of a whole run, on every channel, with the lcm.jar of Debian's
liblcm-java and of PyPI's lcm (whichever are here). `rekon spy` names the fix when the jar is missing."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import BIN_DIR, BUILD_DIR, SHARED_DATA, SOURCE_DIR, in_netns, rekon

JAR = BUILD_DIR / "java" / "rekon_msgs.jar"
LCM_JARS = [p for p in (Path("/usr/share/java/lcm.jar"),
                        *sorted((SOURCE_DIR / ".venv" / "lib").glob("python3*/site-packages/share/java/lcm.jar")))
            if p.exists()]
URL = "udpm://239.255.76.67:7667?ttl=0"
# Every channel a run of the whole pipeline uses (README's message table).
RUN_CHANNELS = ["REKON_FRAMES", "REKON_FRAME_ACK", "REKON_END_OF_STREAM", "REKON_TRACKED_FRAMES", "REKON_KEYFRAMES",
                "REKON_CONSTRAINTS", "REKON_GRAPH_UPDATES", "REKON_MESH_BLOCKS", "REKON_MESH_REQUEST",
                "REKON_HEARTBEAT", "REKON_DONE", "REKON_STATS"]


@pytest.fixture(scope="module")
def run_log(tmp_path_factory) -> Path:
    """lcm-logger's log of `rekon run` on TUM's teddy (200 frames), with `rekon listen --mesh` asking for the map."""
    data = SHARED_DATA / "tum_fr3_teddy_200"
    if not data.is_dir():
        pytest.skip(f"{data} is not here (REKON_SHARED_DATA)")
    d = tmp_path_factory.mktemp("spy")
    logger = shutil.which("lcm-logger") or str(SOURCE_DIR / ".venv" / "bin" / "lcm-logger")
    script = (f"{logger} -q \"--lcm-url={URL}\" {d}/run.lcm & g=$!; timeout 200 {BIN_DIR}/rekon listen --mesh "
              f"{d}/mesh.ply --out {d}/listen > {d}/listen.log 2>&1 & l=$!; sleep 0.5; timeout 200 {BIN_DIR}/rekon run "
              f"--dataset {data} --out {d}/run > {d}/run.log 2>&1; r=$?; wait $l; ll=$?; sleep 0.5; kill $g; wait $g; "
              f"[ $r$ll = 00 ]")
    p = in_netns(script, timeout=260)
    assert p.returncode == 0, p.stdout + (d / "run.log").read_text()[-3000:]
    return d / "run.lcm"


@pytest.fixture(scope="module")
def decoder(tmp_path_factory) -> Path:
    if not shutil.which("javac") or not JAR.exists() or not LCM_JARS:
        pytest.skip(f"no JDK, lcm.jar or {JAR} (apt-get install default-jdk-headless liblcm-java; tools/rekon setup)")
    d = tmp_path_factory.mktemp("decoder")
    subprocess.run(["javac", "-cp", str(LCM_JARS[0]), "-d", str(d), str(Path(__file__).parent / "DecodeLog.java")],
                   check=True, timeout=120)
    return d


@pytest.mark.parametrize("lcm_jar", LCM_JARS, ids=lambda p: "pypi" if ".venv" in str(p) else "debian")
def test_the_jar_decodes_every_event_of_a_runs_log_on_every_channel(run_log, decoder, lcm_jar):
    p = subprocess.run(["java", "-cp", f"{lcm_jar}:{JAR}:{decoder}", "DecodeLog", str(run_log), "REKON_"],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
    print(p.stdout)
    assert p.returncode == 0 and " failed 0" in p.stdout.splitlines()[-1], p.stdout
    lines = {line.split()[0]: line for line in p.stdout.splitlines() if line.startswith("REKON_")}
    for channel in RUN_CHANNELS:
        assert channel in lines, f"{channel} is not in the log:\n{p.stdout}"
    for channel, line in lines.items():
        events, decoded = int(line.split()[2]), int(line.split()[4])
        assert events > 0 and decoded == events and "rekon_msgs." in line, line


def test_rekon_spy_without_the_jar_names_the_fix(tmp_path):
    p = subprocess.run([str(BIN_DIR / "rekon"), "spy"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                       timeout=30, env={**os.environ, "REKON_BUILD_DIR": str(tmp_path)})
    assert p.returncode == 1 and len(p.stdout.strip().splitlines()) == 1, p.stdout
    assert "rekon_msgs.jar is missing" in p.stdout and "default-jdk-headless" in p.stdout, p.stdout


def test_rekon_spy_without_a_display_names_the_fix():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    p = subprocess.run([str(BIN_DIR / "rekon"), "spy"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                       timeout=30, env=env)
    assert p.returncode == 1 and len(p.stdout.strip().splitlines()) == 1, p.stdout
    assert "no display" in p.stdout and "ssh -X" in p.stdout, p.stdout


def test_rekon_spy_help_names_the_bus_option():
    assert "--lcm-url" in rekon("spy", "--help").stdout
