"""rekon-realsense-write: a TUM RGB-D folder (rgb.txt, depth.txt, camera.yaml)
recorded into a RealSense .bag by Intel's SDK itself: the frames are fed, at
their recorded rate, to an rs.software_device (a depth sensor with z16 and
depth units from camera.yaml's depth_scale, a color sensor with rgb8, both
with camera.yaml's intrinsics and an identity extrinsic: the dataset's depth
is already registered to color), wrapped in rs.recorder, which writes the
bag in librealsense's own rosbag layout. The recorder stamps each message
with the time it arrived, so the frames are fed in real time: a bag plays back
at the rate it was fed. Each frame carries its dataset time as its device
timestamp (ms from the first frame, hardware_clock domain; times --slowdown)
and its index + 1 as its frame number, so a run's frames can be traced back
to the dataset's. A machine too busy to feed them on time records its stall:
the playback reproduces it (the tool says how far behind it fed)."""
import argparse
import os
import sys
import time

import numpy as np
import yaml
from PIL import Image


def fail(line):
    print(f"rekon-realsense-write: error: {line}", file=sys.stderr)
    sys.exit(1)


def read_index(path):
    out = []
    try:
        with open(path, encoding="utf-8") as f:
            for line in f:
                parts = line.split()
                if len(parts) >= 2 and not line.startswith("#"):
                    out.append((float(parts[0]), parts[1]))
    except OSError:
        fail(f"{path}: cannot read; give a TUM RGB-D folder (rgb.txt, depth.txt, camera.yaml)")
    return out


def read_camera(path):
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError:
        fail(f"{path}: cannot read; the dataset needs its camera.yaml")
    c = yaml.safe_load(text)
    keys = ("width", "height", "fx", "fy", "cx", "cy", "depth_scale")
    if isinstance(c, str) or isinstance(c, (int, float)):  # the one-line form "640 480 fx fy cx cy scale"
        c = dict(zip(keys, (float(v) for v in str(c).split())))
    if not isinstance(c, dict) or any(k not in c for k in keys):
        fail(f"{path}: needs {', '.join(keys)}")
    return {k: float(c[k]) for k in keys}


def associate(rgb, depth, max_dt=0.02):
    """Each color image with the depth image nearest in time (within max_dt), as rekon's TumDataset."""
    times = np.array([t for t, _ in depth])
    pairs = []
    for t, name in rgb:
        j = int(np.argmin(np.abs(times - t))) if len(times) else -1
        if j >= 0 and abs(times[j] - t) <= max_dt:
            pairs.append((t, name, depth[j][1]))
    return pairs


def load_depth(path):
    a = np.array(Image.open(path))
    if a.ndim != 2:
        fail(f"{path}: depth must be a single-channel 16-bit image")
    return np.ascontiguousarray(a.astype(np.uint16))


def load_color(path):
    return np.ascontiguousarray(np.array(Image.open(path).convert("RGB")))


def main(argv=None):
    p = argparse.ArgumentParser(prog="rekon-realsense-write", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="example:\n  rekon-realsense-write --dataset out/room --out room.bag\n"
                                       "  rekon run --camera realsense --playback room.bag --out out/room_rs")
    p.add_argument("--dataset", required=True, help="TUM RGB-D folder with camera.yaml")
    p.add_argument("--out", required=True, help="the .bag file to write (must not exist)")
    p.add_argument("--frames", type=int, default=0, help="at most this many frames (0 = all)")
    p.add_argument("--fps", type=int, default=30, help="the dataset's rate (the bag's stream info says fps / slowdown)")
    p.add_argument("--slowdown", type=int, default=1, help="record K times slower than the dataset (a 30 Hz dataset "
                                                           "becomes a 30/K Hz recording; device times scaled alike)")
    p.add_argument("--streams", default="depth,color", help="streams to record: depth,color (color alone makes a "
                                                             "bag without depth, for tests)")
    p.add_argument("--serial", default="REKONSYNTH", help="the serial number the bag's device reports")
    a = p.parse_args(argv)
    try:
        import pyrealsense2 as rs
    except ImportError:
        fail("Intel's RealSense SDK (the pyrealsense2 package) is not installed; run tools/rekon deps")
    if os.path.exists(a.out):
        fail(f"{a.out}: already exists; give a new file, nothing is overwritten")
    if a.slowdown < 1 or a.fps % a.slowdown:
        fail(f"--slowdown {a.slowdown}: give a whole number that divides --fps {a.fps}")
    streams = [s for s in a.streams.split(",") if s]
    if not streams or any(s not in ("depth", "color") for s in streams):
        fail(f"--streams {a.streams}: use depth,color, depth or color")
    k = read_camera(os.path.join(a.dataset, "camera.yaml"))
    pairs = associate(read_index(os.path.join(a.dataset, "rgb.txt")), read_index(os.path.join(a.dataset, "depth.txt")))
    if a.frames > 0:
        pairs = pairs[:a.frames]
    if not pairs:
        fail(f"{a.dataset}: no color image has a depth image within 20 ms; check rgb.txt and depth.txt")
    w, h = int(k["width"]), int(k["height"])

    intr = rs.intrinsics()
    intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy = w, h, k["fx"], k["fy"], k["cx"], k["cy"]
    intr.model, intr.coeffs = rs.distortion.none, [0.0] * 5
    dev = rs.software_device()
    dev.register_info(rs.camera_info.name, "rekon dataset " + os.path.basename(os.path.abspath(a.dataset)))
    dev.register_info(rs.camera_info.serial_number, a.serial)
    sensors, profiles = {}, {}
    for uid, (kind, name, fmt, bpp) in enumerate([("depth", "Stereo Module", rs.format.z16, 2),
                                                   ("color", "RGB Camera", rs.format.rgb8, 3)]):
        if kind not in streams:
            continue
        sensor = dev.add_sensor(name)
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid = getattr(rs.stream, kind), 0, uid
        vs.width, vs.height, vs.fps, vs.bpp, vs.fmt, vs.intrinsics = w, h, a.fps // a.slowdown, bpp, fmt, intr
        profiles[kind] = sensor.add_video_stream(vs, True)
        if kind == "depth":
            sensor.add_read_only_option(rs.option.depth_units, 1.0 / k["depth_scale"])
        sensors[kind] = sensor
    if len(profiles) == 2:
        identity = rs.extrinsics()
        identity.rotation, identity.translation = [1, 0, 0, 0, 1, 0, 0, 0, 1], [0, 0, 0]
        profiles["depth"].register_extrinsics_to(profiles["color"], identity)
    recorder = rs.recorder(a.out, dev)
    for kind, sensor in sensors.items():
        sensor.open(profiles[kind])
        sensor.start(lambda f: None)

    t0_data, t0 = pairs[0][0], time.monotonic()
    late = 0.0
    for i, (t, rgb_name, depth_name) in enumerate(pairs):
        images = {}
        if "depth" in sensors:
            images["depth"] = load_depth(os.path.join(a.dataset, depth_name))
        if "color" in sensors:
            images["color"] = load_color(os.path.join(a.dataset, rgb_name))
        for kind, img in images.items():
            if img.shape[:2] != (h, w):
                fail(f"{kind} image of {rgb_name} is {img.shape[1]}x{img.shape[0]}, camera.yaml says {w}x{h}")
        wait = t0 + (t - t0_data) * a.slowdown - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        late = max(late, -wait)
        for kind, img in images.items():
            f = rs.software_video_frame()
            f.pixels, f.bpp = img, (2 if kind == "depth" else 3)
            f.stride = w * f.bpp
            f.timestamp = (t - t0_data) * a.slowdown * 1e3
            f.domain = rs.timestamp_domain.hardware_clock
            f.frame_number = i + 1
            f.profile = profiles[kind].as_video_stream_profile()
            if kind == "depth":
                f.depth_units = 1.0 / k["depth_scale"]
            sensors[kind].on_video_frame(f)
    for sensor in sensors.values():
        sensor.stop()
        sensor.close()
    del recorder  # closes the bag
    print(f"{a.out}: {len(pairs)} frames ({', '.join(streams)} {w}x{h} at {a.fps // a.slowdown} Hz, "
          f"{(pairs[-1][0] - t0_data) * a.slowdown:.2f} s); fed at most {late * 1e3:.0f} ms behind their time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
