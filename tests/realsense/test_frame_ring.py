"""rekon-realsense's shared-memory frame ring, written from Python
(rekon_realsense/frame_ring.py), read by the C++ receivers' own
FrameRingReader (realsense_frame_ring_probe, a child process): the frame bit
for bit, a slot written again dropped as overwritten, a slot written while it
is read dropped as torn; and the segment's life: a stale one replaced, a live
one refused, removed at close."""
import logging
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from conftest import BIN

from rekon_realsense.errors import Error
from rekon_realsense.frame_ring import FrameRingWriter, segment_path

log = logging.getLogger("test")


@pytest.fixture
def name():
    n = f"rekon_test_ring_{os.getpid()}"
    yield n
    if os.path.exists(segment_path(n)):
        os.unlink(segment_path(n))


@pytest.fixture
def ring(name):
    w = FrameRingWriter(name, 4, 640, 480, log)
    yield w
    w.close()


class Probe:
    """The C++ FrameRingReader in a child process, one command per line."""

    def __init__(self):
        self.p = subprocess.Popen([os.path.join(BIN, "realsense_frame_ring_probe")], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True)

    def ask(self, line):
        self.p.stdin.write(line + "\n")
        self.p.stdin.flush()
        return self.p.stdout.readline().strip()

    def close(self):
        self.p.stdin.close()
        assert self.p.wait(timeout=10) == 0


@pytest.fixture
def probe():
    p = Probe()
    yield p
    p.close()


def frame(seed, w=640, h=480):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 65535, (h, w), np.uint16), rng.integers(0, 255, (h, w, 3), np.uint8)


def read_back(probe, ring, slot, generation, tmp_path):
    out = tmp_path / "frame.bin"
    answer = probe.ask(f"read {ring.name} {slot} {generation} {out}")
    return answer, out


def test_the_cpp_reader_reads_the_frame_bit_for_bit_with_color_as_bgr(ring, probe, tmp_path):
    depth, rgb = frame(1)
    generation = ring.write(3, 42, 1796516087.518566, depth, rgb)
    answer, out = read_back(probe, ring, 3, generation, tmp_path)
    word, frame_id, timestamp, w, h = answer.split()
    assert (word, int(frame_id), float(timestamp), int(w), int(h)) == ("ok", 42, 1796516087.518566, 640, 480)
    data = np.fromfile(out, np.uint8)
    assert np.array_equal(data[:640 * 480 * 2].view(np.uint16).reshape(480, 640), depth)
    assert np.array_equal(data[640 * 480 * 2:].reshape(480, 640, 3), rgb[:, :, ::-1])  # the C++ frames' BGR


def test_a_frame_smaller_than_the_slot_reads_at_its_own_size(ring, probe, tmp_path):
    depth, rgb = frame(2, 320, 240)
    generation = ring.write(0, 7, 1.5, depth, rgb)
    answer, out = read_back(probe, ring, 0, generation, tmp_path)
    assert answer.split()[3:] == ["320", "240"]
    assert np.array_equal(np.fromfile(out, np.uint8)[:320 * 240 * 2].view(np.uint16).reshape(240, 320), depth)


def test_a_slot_written_again_is_dropped_as_overwritten_and_the_new_frame_reads(ring, probe, tmp_path):
    first = ring.write(1, 1, 1.0, *frame(3))
    second = ring.write(1, 5, 2.0, *frame(4))  # frame 5 of a 4-slot ring takes frame 1's slot
    assert second == first + 2  # one write, one step of the seqlock's two
    assert read_back(probe, ring, 1, first, tmp_path)[0] == "overwritten"
    assert read_back(probe, ring, 1, second, tmp_path)[0].split()[:2] == ["ok", "5"]


def test_a_slot_written_while_the_cpp_reader_copies_it_is_dropped_as_torn(ring, probe):
    generation = ring.write(2, 2, 1.0, *frame(5))
    probe.p.stdin.write(f"torn {ring.name} 2 {generation}\n")
    probe.p.stdin.flush()
    assert probe.p.stdout.readline().strip() == "copying"  # the reader holds its copy, unchecked
    ring.write(2, 6, 2.0, *frame(6))
    assert probe.ask("go") == "torn"


def test_generations_are_even_and_differ_between_two_instances_of_the_name(name):
    # A receiver still mapping a previous instance never finds a new frame's
    # generation there (as the C++ writer: each instance starts at its own base).
    a = FrameRingWriter(name, 2, 64, 48, log)
    ga = a.write(0, 0, 0.0, *frame(7, 64, 48))
    a.close()
    b = FrameRingWriter(name, 2, 64, 48, log)
    gb = b.write(0, 0, 0.0, *frame(7, 64, 48))
    b.close()
    assert ga % 2 == 0 and gb % 2 == 0 and ga != gb


def test_the_segment_is_removed_at_close(name):
    w = FrameRingWriter(name, 2, 64, 48, log)
    assert os.path.exists(segment_path(name))
    w.close()
    assert not os.path.exists(segment_path(name))


def test_a_segment_left_by_a_killed_writer_is_replaced_with_a_warning(name, caplog):
    code = ("import logging, sys, time; from rekon_realsense.frame_ring import FrameRingWriter; "
            f"FrameRingWriter({name!r}, 2, 64, 48, logging.getLogger()); print('ready', flush=True); time.sleep(60)")
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert child.stdout.readline().strip() == "ready"
    with pytest.raises(Error, match=rf"'{name}' is in use by a running rekon \(pid {child.pid}\); stop it or choose "
                                    "another transport.segment"):
        FrameRingWriter(name, 2, 64, 48, log)
    child.send_signal(signal.SIGKILL)
    child.wait()
    with caplog.at_level(logging.WARNING):
        w = FrameRingWriter(name, 2, 64, 48, log)
    w.close()
    assert f"removing stale shared-memory segment '{name}' left by a crashed run (pid {child.pid})" in caplog.text


def test_a_frame_larger_than_a_slot_is_one_line_naming_both_sizes_and_the_keys(ring):
    with pytest.raises(Error, match=r"frame 9 is 1280x720, larger than a frame-ring slot \(640x480\); set "
                                    r"transport.max_width to at least 1280 and transport.max_height to at least 720"):
        ring.write(0, 9, 0.0, *frame(8, 1280, 720))
