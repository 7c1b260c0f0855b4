"""The shared-memory frame ring written from Python: the segment layout and
seqlock of common/include/rekon/common/frame_ring.hpp (FrameRingWriter in
common/src/frame_ring.cpp), so that the C++ receivers (FrameRingReader,
FrameReceiver) read rekon-realsense's frames unchanged. A frame_t then
carries only the segment's name, the slot and its generation: 1.5 MB a frame
is copied once into the ring instead of through every socket on the bus.

Layout (little-endian; header and slot headers padded to 64 bytes):
  RingHeader { u64 magic, u32 layout_version, i32 creator_pid,
               u64 creator_start_ticks, i32 slots, i32 max_width,
               i32 max_height, i32 reserved, u64 slot_bytes }
  Slot[i]    { u64 sequence, i64 frame_id, f64 timestamp, i32 width,
               i32 height, pad to 64, depth u16[w*h], color bgr8[w*h*3] }
A slot's sequence is odd while it is written and even when complete; the
frame_t's generation is the sequence after the write. Each segment instance
starts its sequences at its own even base (its creation time in ns), as the
C++ writer does, so a receiver that still maps an earlier instance of the
name never takes a new generation for an old frame.

The seqlock's order (sequence odd, payload, sequence even) needs the three
stores to become visible in program order. Python has no fences: x86-64 keeps
stores in order (TSO) and each store here is a separate call, so the order
holds there; elsewhere (ARM) it does not, and `supported()` says no, so
transport.mode auto chooses inline LCM there."""
import mmap
import os
import platform
import struct
import time

import numpy as np

from .errors import Error

MAGIC = 0x31524652454B4552  # "REKERFR1"
LAYOUT_VERSION = 1
ALIGN = 64
HEADER = struct.Struct("<QIiQiiiiQ")  # RingHeader
SLOT_HEADER = struct.Struct("<qdii")  # SlotHeader after its u64 sequence
SHM_DIR = "/dev/shm"  # where POSIX shm_open (Boost.Interprocess) keeps a segment on Linux


def _align_up(n):
    return (n + ALIGN - 1) // ALIGN * ALIGN


HEADER_BYTES = _align_up(HEADER.size)
SLOT_HEADER_BYTES = _align_up(8 + SLOT_HEADER.size)


def slot_bytes(width, height):
    return SLOT_HEADER_BYTES + _align_up(width * height * 5)


def supported():
    """Whether the seqlock's store order holds for a Python writer on this machine (see above)."""
    return platform.machine().lower() in ("x86_64", "amd64")


def process_start_ticks(pid):
    """Field 22 of /proc/PID/stat (start time in clock ticks since boot), so a
    recycled pid is not mistaken for a segment's creator; 0 when unknown."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
            s = f.read()
    except OSError:
        return 0
    fields = s[s.rfind(")") + 2:].split()
    return int(fields[19]) if len(fields) > 19 else 0  # fields[0] is field 3


def _creator_alive(pid, start_ticks):
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # alive, another user's
    return process_start_ticks(pid) == start_ticks


def segment_path(name):
    return os.path.join(SHM_DIR, name)


def remove_stale(name, log):
    """A segment of this name left by a crashed run is removed with a warning;
    one whose creator still runs is an error naming it (as FrameRingWriter)."""
    path = segment_path(name)
    try:
        with open(path, "rb") as f:
            head = f.read(HEADER.size)
    except FileNotFoundError:
        return
    except OSError as e:
        raise Error(f"shared-memory segment '{name}' exists but cannot be read ({e.strerror}); remove {path} "
                    "or choose another transport.segment") from None
    pid = 0
    if len(head) == HEADER.size:
        magic, _, pid, start_ticks, *_ = HEADER.unpack(head)
        if magic == MAGIC and _creator_alive(pid, start_ticks):
            raise Error(f"shared-memory segment '{name}' is in use by a running rekon (pid {pid}); stop it or choose "
                        "another transport.segment")
    log.warning("removing stale shared-memory segment '%s' left by a crashed run (pid %d)", name, pid)
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


class FrameRingWriter:
    """Creates segment `name` (removing a stale one); write() fills a slot;
    close() removes the segment. Frames are 16-bit depth and 8-bit RGB of one
    size (the ring holds BGR, as the C++ frames)."""

    def __init__(self, name, slots, max_width, max_height, log):
        if not 2 <= slots <= 1024:
            raise Error(f"transport.slots = {slots} must be between 2 and 1024")
        if not (0 < max_width <= 8192 and 0 < max_height <= 8192):
            raise Error("transport.max_width/max_height must be between 1 and 8192")
        if not name or "/" in name:
            raise Error(f"transport.segment '{name}' must be a name without '/'")
        remove_stale(name, log)
        self.name, self.slots = name, slots
        self.max_width, self.max_height = max_width, max_height
        self.slot_bytes = slot_bytes(max_width, max_height)
        total = HEADER_BYTES + self.slot_bytes * slots
        self._path = segment_path(name)
        try:
            fd = os.open(self._path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
        except OSError as e:
            raise Error(f"cannot create shared-memory segment '{name}' ({e.strerror}); is {SHM_DIR} mounted and "
                        "writable? otherwise set transport.mode: lcm") from None
        try:
            os.ftruncate(fd, total)  # zero-filled
            self._map = mmap.mmap(fd, total, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        except OSError as e:
            os.unlink(self._path)
            raise Error(f"cannot create shared-memory segment '{name}' of {total >> 20} MiB ({e.strerror}); free "
                        f"{SHM_DIR} or lower transport.slots") from None
        finally:
            os.close(fd)
        self._owner = os.getpid()
        # Each sequence an aligned 8-byte word, stored by one machine store.
        self._seq = [np.ndarray((1,), np.uint64, self._map, self._slot_offset(i)) for i in range(slots)]
        base = time.time_ns() & ~1
        for s in self._seq:
            s[0] = base
        pid = os.getpid()
        HEADER.pack_into(self._map, 0, 0, LAYOUT_VERSION, pid, process_start_ticks(pid), slots, max_width,
                         max_height, 0, self.slot_bytes)
        struct.pack_into("<Q", self._map, 0, MAGIC)  # last: never a half-initialised header that looks valid

    def _slot_offset(self, slot):
        return HEADER_BYTES + self.slot_bytes * slot

    def write(self, slot, frame_id, timestamp, depth, color_rgb):
        """Copies one frame into `slot`; returns the slot's new generation."""
        if not 0 <= slot < self.slots:
            raise Error(f"frame ring slot {slot} out of range")
        h, w = depth.shape
        if w > self.max_width or h > self.max_height:
            raise Error(f"frame {frame_id} is {w}x{h}, larger than a frame-ring slot ({self.max_width}x"
                        f"{self.max_height}); set transport.max_width to at least {w} and transport.max_height to at "
                        f"least {h}")
        if depth.dtype != np.uint16 or color_rgb.dtype != np.uint8 or color_rgb.shape != (h, w, 3):
            raise Error(f"frame {frame_id} is not 16-bit depth and 8-bit colour of one size (a frame source bug)")
        off = self._slot_offset(slot)
        seq = self._seq[slot]
        generation = int(seq[0]) + 2
        seq[0] = generation - 1  # odd: being written
        SLOT_HEADER.pack_into(self._map, off + 8, frame_id, timestamp, w, h)
        payload = off + SLOT_HEADER_BYTES
        np.copyto(np.ndarray((h, w), np.uint16, self._map, payload), depth)
        bgr = np.ndarray((h, w, 3), np.uint8, self._map, payload + w * h * 2)
        for c in range(3):  # RGB to BGR a channel at a time: 0.3 ms where one reversed copy takes 1.6 ms
            bgr[:, :, c] = color_rgb[:, :, 2 - c]
        seq[0] = generation  # even: complete
        return generation

    def close(self):
        """Removes the segment (once, and only in the process that made it)."""
        if self._map is None:
            return
        self._seq = []
        try:
            self._map.close()
        except BufferError:
            pass  # a view still exported: the mapping goes with the process
        self._map = None
        if os.getpid() == self._owner:
            try:
                os.unlink(self._path)
            except FileNotFoundError:
                pass
