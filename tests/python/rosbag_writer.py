"""Writes a TUM-layout dataset as a ROS 1 bag or a ROS 2 bag (sqlite3 or mcap) with rosbags, as a camera
driver would have recorded it: the tests' input for `rekon import bag`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image


def read_index(path: Path) -> list[tuple[str, str]]:
    """(timestamp text, relative path) of a TUM rgb.txt/depth.txt."""
    out = []
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            stamp, rel = line.split()[:2]
            out.append((stamp, rel))
    return out


def read_camera(path: Path) -> dict:
    text = path.read_text()
    values = {}
    for line in text.splitlines():
        line = line.split("#")[0].strip()
        if ":" in line:
            k, v = line.split(":", 1)
            values[k.strip()] = float(v)
        elif line:
            nums = [float(x) for x in line.split()]
            values = dict(zip(["width", "height", "fx", "fy", "cx", "cy", "depth_scale"], nums))
    return values


def png_pixels(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        if im.mode in ("I;16", "I;16B", "I"):
            return np.asarray(im, dtype=np.uint16) if im.mode != "I" else np.asarray(im).astype(np.uint16)
        return np.asarray(im.convert("RGB") if im.mode not in ("RGB", "L") else im)


def _stamp(text: str) -> tuple[int, int]:
    sec, _, frac = text.partition(".")
    return int(sec), int((frac + "000000000")[:9])


class BagWriter:
    """kind: 'ros1', 'sqlite3' or 'mcap'."""

    def __init__(self, path: Path, kind: str):
        from rosbags.typesys import Stores, get_typestore

        self.kind = kind
        if kind == "ros1":
            from rosbags.rosbag1 import Writer

            from rosbags.typesys import get_types_from_msg

            self.ts = get_typestore(Stores.ROS1_NOETIC)
            # TUM's bags carry ROS 1's tf/tfMessage on /tf, which the Noetic store lacks.
            self.ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf/msg/tfMessage"))
            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            self.ts = get_typestore(Stores.ROS2_HUMBLE)
            plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(path, version=9, storage_plugin=plugin)
        self.writer.open()
        self.connections = {}
        self.seq = 0

    @property
    def tf_type(self) -> str:
        return "tf/msg/tfMessage" if self.kind == "ros1" else "tf2_msgs/msg/TFMessage"

    def add(self, topic: str, msgtype: str):
        self.connections[topic] = (self.writer.add_connection(topic, msgtype, typestore=self.ts), msgtype)

    def write(self, topic: str, msg, stamp_ns: int):
        conn, msgtype = self.connections[topic]
        data = self.ts.serialize_ros1(msg, msgtype) if self.kind == "ros1" else self.ts.serialize_cdr(msg, msgtype)
        self.writer.write(conn, stamp_ns, data)

    def close(self):
        self.writer.close()

    # message builders
    def header(self, stamp: str, frame: str):
        T = self.ts.types
        sec, nsec = _stamp(stamp)
        time = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        self.seq += 1
        if self.kind == "ros1":
            return T["std_msgs/msg/Header"](seq=self.seq, stamp=time, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=time, frame_id=frame)

    def image(self, stamp: str, frame: str, pixels: np.ndarray, encoding: str):
        h, w = pixels.shape[:2]
        data = np.ascontiguousarray(pixels).view(np.uint8).reshape(-1)
        return self.ts.types["sensor_msgs/msg/Image"](header=self.header(stamp, frame), height=h, width=w,
                                                      encoding=encoding, is_bigendian=0, step=data.size // h, data=data)

    def compressed(self, stamp: str, frame: str, data: bytes, fmt: str):
        return self.ts.types["sensor_msgs/msg/CompressedImage"](header=self.header(stamp, frame), format=fmt,
                                                                data=np.frombuffer(data, dtype=np.uint8))

    def camera_info(self, stamp: str, frame: str, cam: dict):
        T = self.ts.types
        k = np.array([cam["fx"], 0, cam["cx"], 0, cam["fy"], cam["cy"], 0, 0, 1], dtype=np.float64)
        p = np.array([cam["fx"], 0, cam["cx"], 0, 0, cam["fy"], cam["cy"], 0, 0, 0, 1, 0], dtype=np.float64)
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        fields = dict(header=self.header(stamp, frame), height=int(cam["height"]), width=int(cam["width"]),
                      distortion_model="plumb_bob", d=np.zeros(5), k=k, r=np.eye(3).reshape(-1), p=p,
                      binning_x=0, binning_y=0, roi=roi)
        if self.kind == "ros1":  # ROS 1 spells the matrices in capitals
            fields = {(k_.upper() if k_ in "dkrp" else k_): v for k_, v in fields.items()}
        return T["sensor_msgs/msg/CameraInfo"](**fields)

    def transform(self, stamp: str, parent: str, child: str, pose: list[float]):
        T = self.ts.types
        tr = T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=pose[0], y=pose[1], z=pose[2]),
                                              rotation=T["geometry_msgs/msg/Quaternion"](x=pose[3], y=pose[4], z=pose[5], w=pose[6]))
        ts = T["geometry_msgs/msg/TransformStamped"](header=self.header(stamp, parent), child_frame_id=child, transform=tr)
        return T[self.tf_type](transforms=[ts])

    def pose_stamped(self, stamp: str, frame: str, pose: list[float]):
        T = self.ts.types
        p = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=pose[0], y=pose[1], z=pose[2]),
                                        orientation=T["geometry_msgs/msg/Quaternion"](x=pose[3], y=pose[4], z=pose[5], w=pose[6]))
        return T["geometry_msgs/msg/PoseStamped"](header=self.header(stamp, frame), pose=p)


def ns(stamp: str) -> int:
    sec, nsec = _stamp(stamp)
    return sec * 1_000_000_000 + nsec


def write_dataset_bag(dataset: Path, bag: Path, kind: str, *, depth_encoding: str, color_encoding: str,
                      depth_topic="/camera/depth/image", color_topic="/camera/rgb/image_color",
                      info_topic="/camera/rgb/camera_info", groundtruth: str | None = None,
                      gt_type: str = "tf", max_frames: int = 0, color_label: str | None = None) -> None:
    """depth_encoding: '16UC1' (the PNG's values must be mm) or '32FC1' (PNG value / depth_scale metres).
    color_encoding: 'rgb8', 'bgr8', 'mono8', 'jpeg' or 'png' (the two last as CompressedImage, the file's bytes).
    info_topic None: no CameraInfo. color_label: the encoding written in the messages instead (a bad-input test)."""
    cam = read_camera(dataset / "camera.yaml")
    depth = read_index(dataset / "depth.txt")
    color = read_index(dataset / "rgb.txt")
    if max_frames:
        depth, color = depth[:max_frames], color[:max_frames]
    w = BagWriter(bag, kind)
    w.add(depth_topic, "sensor_msgs/msg/Image")
    compressed = color_encoding in ("jpeg", "png")
    w.add(color_topic, "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image")
    if info_topic:
        w.add(info_topic, "sensor_msgs/msg/CameraInfo")
    if groundtruth:
        w.add(groundtruth, w.tf_type if gt_type == "tf" else "geometry_msgs/msg/PoseStamped")
    events = [(ns(s), 0, s, r) for s, r in depth] + [(ns(s), 1, s, r) for s, r in color]
    if groundtruth and (dataset / "groundtruth.txt").exists():
        for s, *rest in (l.split() for l in (dataset / "groundtruth.txt").read_text().splitlines()
                         if l.strip() and not l.startswith("#")):
            events.append((ns(s), 2, s, [float(v) for v in rest]))
    events.sort(key=lambda e: (e[0], e[1]))
    for t, kind_, stamp, payload in events:
        if kind_ == 0:
            raw = png_pixels(dataset / payload)
            if depth_encoding == "32FC1":
                pixels = (raw.astype(np.float32) / np.float32(cam["depth_scale"])).astype(np.float32)
                pixels[raw == 0] = np.nan
            else:
                pixels = raw.astype(np.uint16)
            w.write(depth_topic, w.image(stamp, "depth_optical", pixels, depth_encoding), t)
        elif kind_ == 1:
            if compressed:
                data = (dataset / payload).read_bytes()
                w.write(color_topic, w.compressed(stamp, "rgb_optical", data, f"rgb8; {color_encoding} compressed bgr8"), t)
            else:
                rgb = png_pixels(dataset / payload)
                pixels = {"rgb8": rgb, "bgr8": rgb[:, :, ::-1], "mono8": rgb if rgb.ndim == 2 else rgb[:, :, 0]}[color_encoding]
                w.write(color_topic, w.image(stamp, "rgb_optical", np.ascontiguousarray(pixels),
                                             color_label or color_encoding), t)
            if info_topic:
                w.write(info_topic, w.camera_info(stamp, "rgb_optical", cam), t)
        else:
            msg = w.transform(stamp, "world", "kinect", payload) if gt_type == "tf" else w.pose_stamped(stamp, "world", payload)
            w.write(groundtruth, msg, t)
    w.close()
