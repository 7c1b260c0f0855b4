"""--record DIR: every captured frame as a TUM RGB-D dataset, as rekon-camera's
recorder (services/camera/src/recorder.cpp): rgb/*.ppm and depth/*.pgm
(uncompressed, so 30 Hz fits on one core), rgb.txt, depth.txt and camera.yaml,
written on its own thread so that capture never waits for the disk: a frame
that finds the queue full is counted as dropped, a failed write as failed
(logged once); the index files are flushed after every frame, so a recording
cut short still opens with `rekon run --dataset DIR`."""
import collections
import logging
import os
import threading

from .errors import Error
from .images import color_ppm, depth_pgm

log = logging.getLogger("rekon")


def save_intrinsics(k, path):
    with open(path, "w", encoding="utf-8") as f:
        for key in ("width", "height", "fx", "fy", "cx", "cy", "depth_scale"):
            v = k[key]
            f.write(f"{key}: {v if isinstance(v, int) else format(v, '.10g')}\n")


class Recorder:
    def __init__(self, folder, k, max_queued):
        self.dir = folder
        self.max_queued = max(1, max_queued)
        if os.path.exists(os.path.join(folder, "rgb.txt")) or os.path.exists(os.path.join(folder, "depth.txt")):
            raise Error(f"{folder}: already holds a recording (rgb.txt); record into a new folder, nothing is "
                        "overwritten")
        try:
            os.makedirs(os.path.join(folder, "rgb"), exist_ok=True)
            os.makedirs(os.path.join(folder, "depth"), exist_ok=True)
            save_intrinsics(k, os.path.join(folder, "camera.yaml"))
            self.rgb_index = open(os.path.join(folder, "rgb.txt"), "w", encoding="utf-8")
            self.depth_index = open(os.path.join(folder, "depth.txt"), "w", encoding="utf-8")
        except OSError as e:
            raise Error(f"{folder}: cannot create the recording folder ({e.strerror})") from None
        self.rgb_index.write("# color images recorded by rekon-realsense\n# timestamp filename\n")
        self.depth_index.write("# depth images recorded by rekon-realsense (depth_scale in camera.yaml)\n"
                               "# timestamp filename\n")
        self.rgb_index.flush()
        self.depth_index.flush()
        self.written = self.dropped = self.failed = 0
        self._queue = collections.deque()
        self._cv = threading.Condition()
        self._closing = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def push(self, frame):
        with self._cv:
            if self._closing or len(self._queue) >= self.max_queued:
                self.dropped += 1
                return
            self._queue.append(frame)
            self._cv.notify()

    def _write(self, f):
        stamp = f"{f.timestamp:.6f}"
        with open(os.path.join(self.dir, "rgb", stamp + ".ppm"), "wb") as out:
            out.write(color_ppm(f.color_rgb))
        with open(os.path.join(self.dir, "depth", stamp + ".pgm"), "wb") as out:
            out.write(depth_pgm(f.depth))
        self.rgb_index.write(f"{stamp} rgb/{stamp}.ppm\n")
        self.rgb_index.flush()
        self.depth_index.write(f"{stamp} depth/{stamp}.pgm\n")
        self.depth_index.flush()

    def _run(self):
        while True:
            with self._cv:
                self._cv.wait_for(lambda: self._queue or self._closing)
                if not self._queue:
                    return
                f = self._queue.popleft()
            try:
                self._write(f)
                ok = True
            except OSError as e:
                ok, why = False, f"{e.filename}: {e.strerror}"
            with self._cv:
                if ok:
                    self.written += 1
                else:
                    if self.failed == 0:
                        log.error("record: %s; later frames are counted as failed", why)
                    self.failed += 1

    def close(self):
        with self._cv:
            self._closing = True
            self._cv.notify()
        self._thread.join()
        self.rgb_index.close()
        self.depth_index.close()
