"""rekon-realsense under the crash-only contract (issue 48, as rekon-camera):
a device lost mid-run is reopened with a doubling wait for
realsense.reconnect_timeout_s, its frame ids going on; one that stays away
ends the run with its line and every output; a killed rekon-realsense is
restarted by rekon run, its frame ids after the newest its consumers have and
a recording going on after the frame they have.

The device that vanishes is the SDK's own playback of a .bag cut short while
it plays: the SDK's reader stops where the file ends (to rekon a device that
vanished), a cut file cannot be opened, and the file made whole again opens
and plays on from where it stopped, as a camera plugged back in streams on.
The 60-frame room is recorded at 15 Hz (4 s; slowdown 2, as the playback
test, for the 2 shared cores)."""
import os
import shutil
import subprocess
import threading
import time

import pytest
import yaml

from conftest import BIN, IN_NETNS, SOURCE, run, stats, write_bag

REKON = os.path.join(BIN, "rekon")
FRAMES, FPS = 60, 15


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    d = tmp_path_factory.mktemp("crash_only")
    rc, text = run([REKON, "synth", "--scene", "room", "--frames", FRAMES, "--out", d / "room"], timeout=600)
    assert rc == 0, text
    write_bag(d / "room", str(d / "room.bag"), slowdown=30 // FPS)
    return str(d / "room.bag")


def read(path):
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except FileNotFoundError:
        return ""


def wait_for_line(path, text, proc):
    """Until `text` is in the log at `path` (True), or the run has ended (False)."""
    while text not in read(path):
        if proc.poll() is not None:
            return text in read(path)
        time.sleep(0.02)
    return True


def poses(out):
    """The trajectory's timestamps, one per pose."""
    with open(os.path.join(out, "trajectory.txt"), encoding="utf-8") as f:
        return [line.split()[0] for line in f if line.strip() and not line.startswith("#")]


def frame_rows(out):
    """(frame id, device frame number) of every row of realsense_frames.csv."""
    with open(os.path.join(out, "realsense_frames.csv"), encoding="utf-8") as f:
        return [tuple(int(v) for v in line.split(",")[:2]) for line in f.read().splitlines()[1:]]


def run_with_the_recording_cut(bag, out, *settings, made_whole=True):
    """rekon run on a copy of `bag` cut to half its bytes once rekon-realsense
    has opened it (the SDK's reader is then at its start: it stops at 1.8 of
    the 3.9 s, measured), and made whole again once rekon-realsense says it is
    reopening it (when `made_whole`). Returns (exit code, output)."""
    cut = os.path.join(os.path.dirname(out), "cut.bag")
    shutil.copyfile(bag, cut)
    log = os.path.join(out, "realsense.log")
    proc = subprocess.Popen([IN_NETNS, REKON, "run", "--camera", "realsense", "--playback", cut, "--out", out, "--set",
                             f"realsense.fps={FPS}"] + [a for s in settings for a in ("--set", s)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    output = []
    reader = threading.Thread(target=lambda: output.append(proc.stdout.read()))
    reader.start()
    try:
        assert wait_for_line(log, "realsense: recording", proc), "rekon-realsense did not open the recording"
        os.truncate(cut, os.path.getsize(bag) // 2)
        if made_whole:
            assert wait_for_line(log, "reopening it", proc), "the cut was not seen as a lost device"
            shutil.copyfile(bag, cut)
        proc.wait(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
        reader.join()
    return proc.returncode, "".join(output)


def test_a_recording_cut_and_made_whole_again_is_reopened_where_it_stopped_and_the_run_goes_on(bag, tmp_path):
    out = str(tmp_path / "run")
    # The first attempt 2 s after the loss: the file is whole again before it
    # (a later attempt, 4 s after that, would only make the outage longer).
    rc, text = run_with_the_recording_cut(bag, out, "realsense.reconnect_wait_s=2")
    realsense_log = read(os.path.join(out, "realsense.log"))
    assert rc == 0, text + realsense_log
    s = stats(os.path.join(out, "realsense_stats.json"))
    print({k: s[k] for k in s if k.startswith(("frames", "outage")) or k in ("end", "clock_resets")})
    assert s["outages"] == 1 and s["end"] == "end of stream"
    assert s["outage_seconds"] >= 2.0  # the first attempt's wait
    assert s["frames_missed_in_outages"] == int(s["outage_seconds"] * FPS)  # at the device's rate
    assert "is back after" in realsense_log
    # It plays on from where it stopped: every device frame once, in order.
    # Measured 59 of the 59 framesets the SDK passes (the syncer's first
    # apart); the seek resumes at the reader's position when the last frame
    # was taken, at most the SDK's queue of 3 framesets ahead of it: 4 of margin.
    rows = frame_rows(out)
    assert [i for i, _ in rows] == list(range(len(rows)))  # frame ids go on over the outage
    numbers = [n for _, n in rows]
    assert all(b > a for a, b in zip(numbers, numbers[1:]))
    assert s["frames_captured"] + s["frames_skipped_late"] >= FRAMES - 1 - 4
    tracked = poses(out)
    assert len(set(tracked)) == len(tracked) == stats(os.path.join(out, "stats.json"))["tracker"]["frames"]
    assert s["frames_sent"] == len(tracked)


def test_a_recording_that_stays_cut_ends_the_run_with_its_line_and_every_output(bag, tmp_path):
    out = str(tmp_path / "run")
    rc, text = run_with_the_recording_cut(bag, out, "realsense.reconnect_timeout_s=2", made_whole=False)
    realsense_log = read(os.path.join(out, "realsense.log"))
    assert rc == 1, text + realsense_log
    assert "reopening it for up to 2 s" in realsense_log
    assert "attempt 1 to reopen it failed" in realsense_log  # 0.25 s, 0.5 s, 1 s: three attempts within the 2 s
    last = text.strip().splitlines()[-1]
    assert "cut.bag: the recording stopped at" in last and "cut short" in last, text
    for f in ("trajectory.txt", "mesh.ply", "stats.json", "camera.yaml", "realsense_frames.csv"):
        assert os.path.exists(os.path.join(out, f)), f
    s = stats(os.path.join(out, "realsense_stats.json"))
    assert s["end"].startswith("device lost: ") and s["outages"] == 0
    # The frames before the cut are all tracked: 27 measured (1.8 s at 15 Hz).
    assert s["frames_sent"] == len(poses(out)) > 0


def test_a_killed_rekon_realsense_is_restarted_and_its_frame_ids_go_on(bag, tmp_path):
    out = str(tmp_path / "run")
    rc, text = run([IN_NETNS, os.path.join(SOURCE, "tests", "faults", "kill_during_run.sh"), BIN, "realsense", 1, out,
                    "--camera", "realsense", "--playback", bag, "--set", f"realsense.fps={FPS}"], timeout=300)
    assert "killed rekon-realsense" in text, text
    assert rc == 0, text + read(os.path.join(out, "run.out"))
    run_stats = stats(os.path.join(out, "stats.json"))
    assert run_stats["restarts"] == {"realsense": 1}
    s = stats(os.path.join(out, "realsense_stats.json"))
    first = s["restarted_at_frame"]
    assert first > 0
    realsense_log = read(os.path.join(out, "realsense.log"))
    assert f"restarted: the consumers have the frames up to {first - 1}; frame ids go on from {first}" in realsense_log
    # The ring made again under its name (the killed writer's segment
    # replaced), and the C++ receivers reading the new one.
    assert "removing stale shared-memory segment" in realsense_log
    assert "was created again" in read(os.path.join(out, "tracker.log"))
    segment = yaml.safe_load(open(os.path.join(out, "config.yaml")))["transport"]["segment"]
    assert not os.path.exists(os.path.join("/dev/shm", segment))
    # realsense_frames.csv keeps both instances' rows (the killed one's
    # written through, the restart's appended): ids from 0, then from `first`.
    rows, n = frame_rows(out), s["frames_captured"]
    ids = [i for i, _ in rows]
    assert ids[:-n] == list(range(len(ids) - n)) and ids[-n:] == list(range(first, first + n))
    # The recording goes on after the device frame the consumers have (frame
    # first - 1): nothing of a file is missed, nothing sent twice. Measured:
    # the very next one (the seek lands 0.3-0.5 s early, the frames up to it
    # not taken); up to 2 more allowed for the SDK's queue on a busy machine.
    had = [number for i, number in rows[:-n] if i == first - 1][-1]
    restart_numbers = [number for _, number in rows[-n:]]
    assert had < restart_numbers[0] <= had + 3, (had, restart_numbers[:3])
    assert f"the recording goes on after its frame {had} " in realsense_log
    # Both instances' frames tracked, each timestamp once: every frame the
    # tracker had has a pose. The killed instance's frames its outlet replaced
    # (after each check of the kill script, which holds it stopped) have ids
    # but never reached the tracker: 0-2 measured in 8 runs, 4 allowed.
    tracked = poses(out)
    print(f"restarted at frame {first} after device frame {had}, the restart's first {restart_numbers[0]}; "
          f"{len(tracked)} poses of {first} + {s['frames_sent']} sent")
    assert len(set(tracked)) == len(tracked), "a timestamp twice"
    assert run_stats["tracker"]["frames"] == len(tracked) and run_stats["tracker"]["lost_frames"] == 0
    assert len(tracked) >= first + s["frames_sent"] - 4
