"""ROS 1 and ROS 2 (sqlite3, mcap) bags to a dataset folder that `rekon run --dataset` reads.

    rekon import bag FILE --list
    rekon import bag FILE --out DATASET [--depth-topic T] [--color-topic T] [--camera-info T]
                                        [--groundtruth T [--gt-frames PARENT CHILD]]

The dataset is TUM RGB-D layout (docs/datasets.md): rgb/ and depth/ PNGs named
by timestamp, rgb.txt and depth.txt listing the associated pairs only, an
optional groundtruth.txt, and camera.yaml from the color camera's CameraInfo.
Depth 16UC1 (millimetres) is written as it is (depth_scale 1000); 32FC1
(metres) as round(metres * --depth-scale) (default 5000, TUM's). Color rgb8,
bgr8 and mono8 images become PNGs; a CompressedImage's JPEG or PNG bytes are
written unchanged. Depth and color are paired by header timestamp as TUM's
associate.py does (closest first, each image once, within --max-dt).
"""

from __future__ import annotations

import argparse
import collections
import concurrent.futures
import contextlib
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import png

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")  # ROS 2 and ROS 2-style ROS 1; ROS 1's own tf (TUM's bags)
GROUND_TRUTH_TYPES = (POSE_STAMPED, POSE_COV_STAMPED, TRANSFORM_STAMPED, ODOMETRY, *TF_TYPES)

DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
COLOR_ENCODINGS = ("rgb8", "bgr8", "mono8", "rgba8", "bgra8")
# Largest depth/color timestamp difference of one frame (TUM associate.py's default, rekon's reader's).
DEFAULT_MAX_DT_S = 0.02
# Depth values per metre written for 32FC1 depth (TUM's own PNGs: 5000, 0.2 mm steps up to 13.1 m).
DEFAULT_FLOAT_DEPTH_SCALE = 5000.0
# Depth values per metre of 16UC1 depth (REP 118: millimetres).
MILLIMETRE_DEPTH_SCALE = 1000.0
PROGRESS_PERIOD_S = 2.0
# PNG encoders working at once (zlib and numpy release the GIL), and images queued to them at most.
PNG_WORKERS = max(1, min(4, os.cpu_count() or 1))
PNG_QUEUE = 2 * PNG_WORKERS


class BagError(Exception):
    """Bad input: the message is one line naming the bag or topic and the fix."""


@dataclass
class Topic:
    name: str
    msgtype: str
    count: int
    first_ns: int = 0
    last_ns: int = 0
    detail: str = ""  # an Image's encoding and size, a CompressedImage's format

    @property
    def rate_hz(self) -> float:
        span = (self.last_ns - self.first_ns) * 1e-9
        return (self.count - 1) / span if self.count > 1 and span > 0 else 0.0


@dataclass
class ImportResult:
    pairs: int
    depth_frames: int
    color_frames: int
    dropped_depth: int  # depth images without a color image within max_dt
    dropped_color: int
    ground_truth_poses: int = 0
    depth_scale: float = 0.0
    topics: dict = field(default_factory=dict)


@contextlib.contextmanager
def _open(path: Path):
    """An open rosbags AnyReader on a ROS 1 bag file or a ROS 2 bag folder (or its .db3/.mcap file)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag; pass a ROS 1 .bag file or a ROS 2 bag folder (metadata.yaml inside)")
    if path.is_file() and path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").exists():
        path = path.parent  # a ROS 2 bag is its folder
    if path.is_file() and path.suffix != ".bag":
        raise BagError(f"{path}: a ROS 1 bag's name ends in .bag and a ROS 2 bag is a folder with metadata.yaml; "
                       f"rename it or pass the folder")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as err:  # noqa: BLE001 - rosbags raises several kinds on damaged files
        raise BagError(f"{path}: not a readable ROS bag ({_one_line(err)}); if it was cut short, "
                       f"re-index it (ROS 1: rosbag reindex; ROS 2: ros2 bag reindex) or record it again") from None
    try:
        yield reader
    finally:
        reader.close()


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) < 200 else text[:197] + "..."


def _messages(reader, connections, bag: Path):
    """reader.messages(), with a damaged bag's error as one BagError line naming the topics read."""
    try:
        yield from reader.messages(connections=connections)
    except BagError:
        raise
    except Exception as err:  # noqa: BLE001 - a truncated chunk surfaces as any of several errors
        names = ", ".join(sorted({c.topic for c in connections}))
        raise BagError(f"{bag}: reading {names} failed ({_one_line(err)}); the bag is damaged or cut short: "
                       f"re-index it (ROS 1: rosbag reindex; ROS 2: ros2 bag reindex) or record it again") from None


def _deserialize(reader, raw, connection, bag):
    try:
        return reader.deserialize(raw, connection.msgtype)
    except Exception as err:  # noqa: BLE001
        raise BagError(f"{bag}: a message on {connection.topic} ({connection.msgtype}) does not decode "
                       f"({_one_line(err)}); the bag is damaged: record it again") from None


def _stamp_s(header) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def list_topics(bag: Path) -> list[Topic]:
    """Every topic with its type, message count, rate (from bag time) and, for images, encoding and size."""
    bag = Path(bag)
    with _open(bag) as reader:
        topics: dict[str, Topic] = {}
        for c in reader.connections:
            t = topics.setdefault(c.topic, Topic(c.topic, c.msgtype, 0))
            t.count += c.msgcount
        for connection, ns, raw in _messages(reader, reader.connections, bag):
            t = topics[connection.topic]
            if not t.first_ns:
                t.first_ns = ns
                if connection.msgtype == IMAGE:
                    m = _deserialize(reader, raw, connection, bag)
                    t.detail = f"{m.encoding} {m.width}x{m.height}"
                elif connection.msgtype == COMPRESSED:
                    t.detail = _deserialize(reader, raw, connection, bag).format
            t.last_ns = ns
    return sorted(topics.values(), key=lambda t: t.name)


def _first_message(reader, connection, bag):
    for c, _, raw in _messages(reader, [connection], bag):
        return _deserialize(reader, raw, c, bag)
    return None


def _choose(candidates: list[str], wanted: str | None, what: str, option: str, all_topics: dict) -> str:
    if wanted:
        if wanted not in all_topics:
            raise BagError(f"{wanted}: no such topic in the bag; {option} takes one of: {', '.join(sorted(all_topics))} "
                           f"(rekon import bag FILE --list)")
        return wanted
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        raise BagError(f"no {what} topic in the bag (rekon import bag FILE --list shows its topics); "
                       f"pass {option} TOPIC")
    raise BagError(f"several {what} topics ({', '.join(sorted(candidates))}): choose one with {option}")


def _camera_info_topic(color: str, wanted: str | None, infos: list[str]) -> str:
    if wanted:
        if wanted not in infos:
            raise BagError(f"{wanted}: not a CameraInfo topic of the bag (CameraInfo topics: {', '.join(infos) or 'none'}); "
                           f"pass --camera-info with one of them or --intrinsics FX FY CX CY")
        return wanted
    sibling = color.rsplit("/", 1)[0] + "/camera_info"
    if sibling in infos:
        return sibling
    raise BagError(f"{color} has no CameraInfo ({sibling} is not in the bag); pass --camera-info TOPIC "
                   f"(the color camera's) or --intrinsics FX FY CX CY")


class _DepthWriter:
    """Depth images to 16-bit PNGs; the first image's encoding fixes the unit."""

    def __init__(self, topic: str, float_scale: float):
        self.topic = topic
        self.float_scale = float_scale
        self.encoding = None
        self.depth_scale = None
        self.out_of_range = 0  # 32FC1 pixels beyond 65535 / scale metres, written as 0 (no depth)

    def pixels(self, m) -> np.ndarray:
        if m.encoding not in DEPTH_ENCODINGS:
            raise BagError(f"{self.topic}: depth encoding '{m.encoding}' is not supported; publish 16UC1 (mm) or "
                           f"32FC1 (m), or pass the right topic with --depth-topic")
        if self.encoding is None:
            self.encoding = m.encoding
            self.depth_scale = self.float_scale if m.encoding == "32FC1" else MILLIMETRE_DEPTH_SCALE
        elif m.encoding != self.encoding:
            raise BagError(f"{self.topic}: depth encoding changes from {self.encoding} to {m.encoding} within the bag; "
                           f"import the parts separately")
        big = ">" if m.is_bigendian else "<"
        if m.encoding == "32FC1":
            metres = _rows(m, np.dtype(big + "f4"), 1, self.topic)
            with np.errstate(invalid="ignore"):
                scaled = np.rint(np.where(np.isfinite(metres) & (metres > 0), metres, 0.0) * self.depth_scale)
            too_far = scaled > 65535
            self.out_of_range += int(too_far.sum())
            scaled[too_far] = 0
            return scaled.astype(np.uint16)
        return _rows(m, np.dtype(big + "u2"), 1, self.topic).astype(np.uint16)


def _rows(m, dtype: np.dtype, channels: int, topic: str) -> np.ndarray:
    """An Image's pixels as (height, width[, channels]), honouring its row step."""
    row = m.width * channels * dtype.itemsize
    data = np.asarray(m.data, dtype=np.uint8)
    if m.step < row or data.size < m.step * (m.height - 1) + row:
        raise BagError(f"{topic}: an image of {m.width}x{m.height} {m.encoding} holds {data.size} bytes with step "
                       f"{m.step}; the message is inconsistent: record it again")
    rows = np.lib.stride_tricks.as_strided(data, shape=(m.height, row), strides=(m.step, 1))
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(m.height, m.width, channels)
    return pixels[:, :, 0] if channels == 1 else pixels


def _color_pixels(m, topic: str) -> np.ndarray:
    if m.encoding not in COLOR_ENCODINGS:
        raise BagError(f"{topic}: color encoding '{m.encoding}' is not supported (rgb8, bgr8, mono8, rgba8, bgra8 "
                       f"or a CompressedImage); republish it as rgb8 (e.g. image_proc) or pass --color-topic")
    channels = {"mono8": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}[m.encoding]
    pixels = _rows(m, np.dtype(np.uint8), channels, topic)
    if m.encoding in ("bgr8", "bgra8"):
        pixels = pixels[:, :, 2::-1]
    elif m.encoding == "rgba8":
        pixels = pixels[:, :, :3]
    return np.ascontiguousarray(pixels)


def _compressed_suffix(m, topic: str) -> str:
    fmt = m.format.lower()
    if "compresseddepth" in fmt:
        raise BagError(f"{topic}: '{m.format}' is compressed depth, not color; pass the color topic with --color-topic")
    if "jpeg" in fmt or "jpg" in fmt:
        return ".jpg"
    if "png" in fmt:
        return ".png"
    raise BagError(f"{topic}: CompressedImage format '{m.format}' is not supported (jpeg or png); "
                   f"republish it uncompressed (rgb8) or as jpeg")


def write_png(path: Path, pixels: np.ndarray) -> None:
    """pixels: (h, w) uint16 (16-bit grey), (h, w) uint8 (grey) or (h, w, 3) uint8 (RGB); encoded as rekon synth
    encodes its frames (rekon.png), so the same pixels give the same file."""
    Path(path).write_bytes(png.encode(pixels))


def associate(depth: list[float], color: list[float], max_dt: float) -> list[tuple[int, int]]:
    """TUM associate.py: pairs within max_dt, closest first, each image at most once; sorted by color time."""
    order = np.argsort(color, kind="stable")
    color_sorted = np.asarray(color)[order]
    candidates = []
    for d, t in enumerate(depth):
        lo = np.searchsorted(color_sorted, t - max_dt, side="left")
        hi = np.searchsorted(color_sorted, t + max_dt, side="right")
        for k in range(lo, hi):
            candidates.append((abs(color_sorted[k] - t), int(order[k]), d))
    candidates.sort()
    used_color, used_depth, pairs = set(), set(), []
    for _, c, d in candidates:
        if c in used_color or d in used_depth:
            continue
        used_color.add(c)
        used_depth.add(d)
        pairs.append((c, d))
    pairs.sort(key=lambda p: color[p[0]])
    return pairs


def _gt_poses(m, msgtype: str, frames: tuple[str, str] | None, topic: str):
    """(timestamp, [tx ty tz qx qy qz qw]) of one ground-truth message; TF yields the transforms of frames."""
    if msgtype in TF_TYPES:
        for tr in m.transforms:
            pair = (tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/"))
            if frames is None or pair == frames:
                yield _stamp_s(tr.header), _transform(tr.transform), pair
        return
    if msgtype == TRANSFORM_STAMPED:
        yield _stamp_s(m.header), _transform(m.transform), None
    elif msgtype == POSE_STAMPED:
        yield _stamp_s(m.header), _pose(m.pose), None
    elif msgtype in (POSE_COV_STAMPED, ODOMETRY):
        yield _stamp_s(m.header), _pose(m.pose.pose), None
    else:
        raise BagError(f"{topic}: {msgtype} is not a ground-truth type (PoseStamped, PoseWithCovarianceStamped, "
                       f"TransformStamped, Odometry, TFMessage); pass another --groundtruth topic")


def _pose(p):
    return [p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w]


def _transform(t):
    return [t.translation.x, t.translation.y, t.translation.z, t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w]


class _PngWriter:
    """write_png on a few threads, with a bounded queue (images are large); errors surface on the next call."""

    def __init__(self):
        self.pool = concurrent.futures.ThreadPoolExecutor(max_workers=PNG_WORKERS)
        self.pending = collections.deque()

    def __call__(self, path: Path, pixels: np.ndarray):
        while len(self.pending) >= PNG_QUEUE:
            self.pending.popleft().result()
        self.pending.append(self.pool.submit(write_png, path, pixels))

    def close(self):
        try:
            while self.pending:
                self.pending.popleft().result()
        finally:
            self.pool.shutdown(wait=True, cancel_futures=True)


class _Progress:
    def __init__(self, total: int, log):
        self.total, self.log, self.done = total, log, 0
        self.start = self.last = time.monotonic()

    def step(self):
        self.done += 1
        now = time.monotonic()
        if now - self.last >= PROGRESS_PERIOD_S:
            self.last = now
            rate = self.done / (now - self.start)
            eta = (self.total - self.done) / rate if rate > 0 else 0
            self.log(f"import: {self.done} of {self.total} images ({100 * self.done // max(self.total, 1)} %), "
                     f"{rate:.0f}/s, ETA {eta:.0f} s")


def import_bag(bag: Path, out: Path, *, depth_topic: str | None = None, color_topic: str | None = None,
               camera_info: str | None = None, intrinsics: list[float] | None = None,
               groundtruth: str | None = None, gt_frames: tuple[str, str] | None = None,
               max_dt: float = DEFAULT_MAX_DT_S, depth_scale: float = DEFAULT_FLOAT_DEPTH_SCALE,
               force: bool = False, log=lambda line: print(line, file=sys.stderr)) -> ImportResult:
    """Writes the dataset folder `out` from `bag`; raises BagError (one line) on bad input.
    The images go to OUT.importing first, which becomes `out` only when everything was read."""
    bag, out = Path(bag), Path(out)
    tmp = out.with_name(out.name + ".importing")
    try:
        return _import_bag(bag, out, tmp, depth_topic, color_topic, camera_info, intrinsics, groundtruth, gt_frames,
                           max_dt, depth_scale, force, log)
    finally:
        if tmp.exists():
            _remove_tree(tmp)


def _import_bag(bag, out, tmp, depth_topic, color_topic, camera_info, intrinsics, groundtruth, gt_frames, max_dt,
                depth_scale, force, log) -> ImportResult:
    if out.exists() and any(out.iterdir()) and not force:
        raise BagError(f"{out}: exists and is not empty; choose another --out or pass --force to replace it")
    with _open(bag) as reader:
        by_topic = {}
        for c in reader.connections:
            by_topic.setdefault(c.topic, []).append(c)
        types = {t: cs[0].msgtype for t, cs in by_topic.items()}

        # Topics by type; an Image's first message says whether it is depth or color.
        depth_candidates, color_candidates = [], []
        for topic, msgtype in types.items():
            if msgtype == COMPRESSED:
                if "depth" not in topic:
                    color_candidates.append(topic)
            elif msgtype == IMAGE:
                m = _first_message(reader, by_topic[topic][0], bag)
                if m is None:
                    continue
                (depth_candidates if m.encoding in DEPTH_ENCODINGS else color_candidates).append(topic)
        depth_topic = _choose(depth_candidates, depth_topic, "depth image (16UC1, 32FC1)", "--depth-topic", types)
        color_topic = _choose(color_candidates, color_topic, "color image (rgb8, bgr8, mono8, CompressedImage)",
                              "--color-topic", types)
        for topic, option, allowed in ((depth_topic, "--depth-topic", (IMAGE,)),
                                       (color_topic, "--color-topic", (IMAGE, COMPRESSED))):
            if types[topic] not in allowed:
                raise BagError(f"{topic}: is {types[topic]}, not an image; pass an Image topic with {option}")
        # The first message of each says whether its encoding is one rekon reads, before anything is written.
        first_depth = _first_message(reader, by_topic[depth_topic][0], bag)
        if first_depth is not None:
            _DepthWriter(depth_topic, depth_scale).pixels(first_depth)
        first_color = _first_message(reader, by_topic[color_topic][0], bag)
        if first_color is not None:
            if types[color_topic] == COMPRESSED:
                _compressed_suffix(first_color, color_topic)
            else:
                _color_pixels(first_color, color_topic)

        if intrinsics is None:
            infos = sorted(t for t, ty in types.items() if ty == CAMERA_INFO)
            info_topic = _camera_info_topic(color_topic, camera_info, infos)
            info = _first_message(reader, by_topic[info_topic][0], bag)
            k = info.k if hasattr(info, "k") else info.K  # ROS 2 spells the matrices in lower case, ROS 1 in capitals
            distortion = info.d if hasattr(info, "d") else info.D
            fx, fy, cx, cy = (float(v) for v in (k[0], k[4], k[2], k[5]))
            if not all(math.isfinite(v) for v in (fx, fy, cx, cy)) or fx <= 0 or fy <= 0:
                raise BagError(f"{info_topic}: K holds no intrinsics (fx {fx}, fy {fy}); the camera was not calibrated: "
                               f"pass --intrinsics FX FY CX CY")
            if any(abs(d) > 1e-9 for d in distortion):
                log(f"import: note: {info_topic} has lens distortion {[float(d) for d in distortion][:5]}; rekon assumes undistorted "
                    f"images (use the rectified topic, image_rect_color, when the bag has it)")
            info_size = (info.width, info.height)
        else:
            info_topic, (fx, fy, cx, cy), info_size = None, intrinsics, None

        gt_type = None
        if groundtruth:
            if groundtruth not in types:
                raise BagError(f"{groundtruth}: no such topic in the bag; --groundtruth takes a PoseStamped, Odometry, "
                               f"TransformStamped or TF topic (rekon import bag FILE --list)")
            gt_type = types[groundtruth]
            if gt_type not in GROUND_TRUTH_TYPES:
                raise BagError(f"{groundtruth}: {gt_type} is not a ground-truth type (PoseStamped, "
                               f"PoseWithCovarianceStamped, TransformStamped, Odometry, TFMessage); pass another "
                               f"--groundtruth topic")

        if tmp.exists():
            _remove_tree(tmp)
        (tmp / "rgb").mkdir(parents=True)
        (tmp / "depth").mkdir()

        wanted = by_topic[depth_topic] + by_topic[color_topic] + (by_topic[groundtruth] if groundtruth else [])
        total = sum(c.msgcount for c in by_topic[depth_topic] + by_topic[color_topic])
        log(f"import: {bag} -> {out}: depth {depth_topic}, color {color_topic}, "
            f"camera {info_topic or 'from --intrinsics'}{', ground truth ' + groundtruth if groundtruth else ''}; "
            f"{total} images")
        progress = _Progress(total, log)
        png = _PngWriter()
        try:
            depth, color, gt, gt_pairs, size, depth_writer = _read_images(
                reader, bag, wanted, png, progress, tmp, depth_topic, color_topic, groundtruth, gt_type, gt_frames,
                depth_scale)
        finally:
            png.close()


        if not depth or not color:
            empty = depth_topic if not depth else color_topic
            raise BagError(f"{empty}: no messages in the bag; pass another topic ({'--depth-topic' if not depth else '--color-topic'})")
        if len(gt_pairs) > 1 and gt_frames is None:
            names = ", ".join(f"{p} {c}" for p, c in sorted(gt_pairs))
            raise BagError(f"{groundtruth}: holds several transforms ({names}); choose one with --gt-frames PARENT CHILD")
        if groundtruth and not gt:
            raise BagError(f"{groundtruth}: no poses{' for ' + ' -> '.join(gt_frames) if gt_frames else ''}; "
                           f"check --gt-frames against rekon import bag FILE --list")

        height, width = size if size else (info_size[1], info_size[0])
        if info_size and info_size != (width, height):
            raise BagError(f"{info_topic}: is for {info_size[0]}x{info_size[1]} images but {color_topic} is "
                           f"{width}x{height}; pass the color camera's CameraInfo with --camera-info")

        pairs = associate([t for t, _ in depth], [t for t, _ in color], max_dt)
        paired_color = {c for c, _ in pairs}
        paired_depth = {d for _, d in pairs}
        for i, (_, rel) in enumerate(color):
            if i not in paired_color:
                (tmp / rel).unlink()
        for i, (_, rel) in enumerate(depth):
            if i not in paired_depth:
                (tmp / rel).unlink()
        source = f"# file: '{bag.name}' (rekon import bag)"
        with open(tmp / "rgb.txt", "w") as f:
            f.write(f"# color images\n{source}\n# timestamp filename\n")
            for c, _ in pairs:
                f.write(f"{color[c][0]:.6f} {color[c][1]}\n")
        with open(tmp / "depth.txt", "w") as f:
            f.write(f"# depth maps\n{source}\n# timestamp filename\n")
            for _, d in pairs:
                f.write(f"{depth[d][0]:.6f} {depth[d][1]}\n")
        if gt:
            gt.sort(key=lambda p: p[0])
            with open(tmp / "groundtruth.txt", "w") as f:
                f.write(f"# ground truth trajectory\n{source}\n# timestamp tx ty tz qx qy qz qw\n")
                for stamp, pose in gt:
                    f.write(f"{stamp:.6f} " + " ".join(repr(float(v)) for v in pose) + "\n")  # exact: shortest round trip
        with open(tmp / "camera.yaml", "w") as f:
            f.write(f"# from {info_topic or '--intrinsics'} of {bag.name} (rekon import bag)\n"
                    f"width: {width}\nheight: {height}\nfx: {fx!r}\nfy: {fy!r}\ncx: {cx!r}\ncy: {cy!r}\n"
                    f"depth_scale: {depth_writer.depth_scale:g}\n")
        if out.exists():
            _remove_tree(out)
        tmp.rename(out)

    result = ImportResult(pairs=len(pairs), depth_frames=len(depth), color_frames=len(color),
                          dropped_depth=len(depth) - len(pairs), dropped_color=len(color) - len(pairs),
                          ground_truth_poses=len(gt), depth_scale=depth_writer.depth_scale,
                          topics={"depth": depth_topic, "color": color_topic, "camera_info": info_topic,
                                  "groundtruth": groundtruth})
    if depth_writer.out_of_range:
        log(f"import: {depth_writer.out_of_range} depth pixels of {depth_topic} beyond {65535 / depth_writer.depth_scale:.1f} m "
            f"written as 0 (no depth); a smaller --depth-scale keeps them")
    log(f"import: {result.pairs} frames ({depth_writer.encoding} depth, depth_scale {depth_writer.depth_scale:g}); "
        f"dropped {result.dropped_depth} of {result.depth_frames} depth and {result.dropped_color} of "
        f"{result.color_frames} color images without a partner within {max_dt * 1000:g} ms"
        + (f"; {len(gt)} ground-truth poses" if gt else ""))
    return result


def _read_images(reader, bag, wanted, png, progress, tmp, depth_topic, color_topic, groundtruth, gt_type, gt_frames,
                 depth_scale):
    """One pass over the bag: every depth and color image written under tmp, ground-truth poses collected."""
    depth_writer = _DepthWriter(depth_topic, depth_scale)
    depth, color = [], []  # (timestamp, relative path)
    gt, gt_pairs = [], set()
    size = None
    names = set()
    for connection, bag_ns, raw in _messages(reader, wanted, bag):
        m = _deserialize(reader, raw, connection, bag)
        topic = connection.topic
        if topic == groundtruth:
            for stamp, pose, pair in _gt_poses(m, gt_type, gt_frames, topic):
                gt.append((stamp, pose))
                if pair:
                    gt_pairs.add(pair)
            continue
        stamp = _stamp_s(m.header) if (m.header.stamp.sec or m.header.stamp.nanosec) else bag_ns * 1e-9
        name = f"{stamp:.6f}"
        if topic == depth_topic:
            pixels = depth_writer.pixels(m)
            size = _check_size(size, pixels.shape, topic)
            rel = _unique(names, "depth", name, ".png")
            png(tmp / rel, pixels)
            depth.append((stamp, rel))
        else:
            if connection.msgtype == COMPRESSED:
                rel = _unique(names, "rgb", name, _compressed_suffix(m, topic))
                (tmp / rel).write_bytes(bytes(m.data))
            else:
                pixels = _color_pixels(m, topic)
                size = _check_size(size, pixels.shape[:2], topic)
                rel = _unique(names, "rgb", name, ".png")
                png(tmp / rel, pixels)
            color.append((stamp, rel))
        progress.step()
    return depth, color, gt, gt_pairs, size, depth_writer


def _check_size(size, shape, topic):
    shape = tuple(shape[:2])
    if size is None or size == shape:
        return shape
    raise BagError(f"{topic}: is {shape[1]}x{shape[0]} but the other images are {size[1]}x{size[0]}; rekon needs depth "
                   f"registered to color (same size): pass a registered depth topic (e.g. depth_registered/image_raw) "
                   f"with --depth-topic")


def _unique(taken: set, folder: str, name: str, suffix: str) -> str:
    """folder/name.suffix, or folder/name_N.suffix when two images share a timestamp."""
    rel = f"{folder}/{name}{suffix}"
    n = 1
    while rel in taken:
        rel = f"{folder}/{name}_{n}{suffix}"
        n += 1
    taken.add(rel)
    return rel


def _remove_tree(path: Path) -> None:
    for root, dirs, files in os.walk(path, topdown=False):
        for f in files:
            os.unlink(os.path.join(root, f))
        for d in dirs:
            os.rmdir(os.path.join(root, d))
    os.rmdir(path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="rekon import bag",
        description="A ROS 1 bag or ROS 2 bag (sqlite3 or mcap) to a TUM-layout dataset folder for rekon run --dataset.",
        epilog="examples:\n  rekon import bag rgbd_dataset_freiburg3_teddy.bag --list\n"
               "  rekon import bag rgbd_dataset_freiburg3_teddy.bag --out data/teddy --groundtruth /tf --gt-frames world kinect\n"
               "  rekon import bag my_ros2_bag/ --out data/mine --depth-topic /camera/aligned_depth_to_color/image_raw",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", help="ROS 1 .bag file, or ROS 2 bag folder (sqlite3 or mcap)")
    p.add_argument("--list", action="store_true", help="print the topics, types, counts and rates, and exit")
    p.add_argument("--out", help="the dataset folder to write")
    p.add_argument("--depth-topic", help="sensor_msgs/Image, 16UC1 (mm) or 32FC1 (m), registered to color")
    p.add_argument("--color-topic", help="sensor_msgs/Image (rgb8, bgr8, mono8) or CompressedImage (jpeg, png)")
    p.add_argument("--camera-info", help="the color camera's CameraInfo (default: camera_info beside the color topic)")
    p.add_argument("--intrinsics", nargs=4, type=float, metavar=("FX", "FY", "CX", "CY"),
                   help="instead of a CameraInfo topic")
    p.add_argument("--groundtruth", help="PoseStamped, Odometry, TransformStamped or TF topic: groundtruth.txt")
    p.add_argument("--gt-frames", nargs=2, metavar=("PARENT", "CHILD"), help="the transform of a TF --groundtruth topic")
    p.add_argument("--max-dt", type=float, default=DEFAULT_MAX_DT_S,
                   help=f"largest depth/color timestamp difference of a frame, s (default {DEFAULT_MAX_DT_S})")
    p.add_argument("--depth-scale", type=float, default=DEFAULT_FLOAT_DEPTH_SCALE,
                   help=f"depth values per metre written for 32FC1 depth (default {DEFAULT_FLOAT_DEPTH_SCALE:g}; "
                        f"16UC1 is kept in mm, 1000)")
    p.add_argument("--force", action="store_true", help="replace a non-empty --out folder")
    a = p.parse_args(argv)
    try:
        if a.list:
            topics = list_topics(Path(a.bag))
            width = max(len(t.name) for t in topics) if topics else 0
            type_width = max(len(t.msgtype) for t in topics) if topics else 0
            for t in topics:
                print(f"{t.name:<{width}}  {t.msgtype:<{type_width}}  {t.count:7d} msgs  {t.rate_hz:7.2f} Hz  {t.detail}".rstrip())
            return 0
        if not a.out:
            raise BagError("--out DATASET is needed (or --list to see the topics)")
        if not (a.depth_scale > 0 and math.isfinite(a.depth_scale)):
            raise BagError(f"--depth-scale {a.depth_scale}: must be a positive number of depth values per metre")
        import_bag(Path(a.bag), Path(a.out), depth_topic=a.depth_topic, color_topic=a.color_topic,
                   camera_info=a.camera_info, intrinsics=a.intrinsics, groundtruth=a.groundtruth,
                   gt_frames=tuple(f.lstrip("/") for f in a.gt_frames) if a.gt_frames else None,
                   max_dt=a.max_dt, depth_scale=a.depth_scale, force=a.force)
        return 0
    except BagError as err:
        print(f"rekon import bag: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
