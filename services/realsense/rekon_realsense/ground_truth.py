"""rekon-realsense-gt: the ground truth of a run from a .bag that
rekon-realsense-write made of a dataset. The bag's frame number n is the
dataset's frame n - 1 (its color image's place among the associated pairs),
and rekon-realsense writes each frame's number beside the host stamp it carried
(<out>/realsense_frames.csv); so the dataset's groundtruth.txt pose of each
frame is written at the stamp the run's trajectory.txt has for it."""
import argparse
import os
import sys

import numpy as np

from .bag_write import associate, fail, read_index


def live_ground_truth(dataset, frames_csv, out_path, slowdown=1):
    pairs = associate(read_index(os.path.join(dataset, "rgb.txt")), read_index(os.path.join(dataset, "depth.txt")))
    gt = [(t, " ".join(rest)) for t, rest in _tum(os.path.join(dataset, "groundtruth.txt"))]
    gt_t = np.array([t for t, _ in gt])
    rows = np.loadtxt(frames_csv, delimiter=",", skiprows=1, ndmin=2)
    written = 0
    with open(out_path, "w", encoding="utf-8") as f:
        f.write("# ground truth of the dataset's frames at the stamps of a rekon-realsense run\n")
        for number, device_ms, stamp in zip(rows[:, 1].astype(int), rows[:, 2], rows[:, 3]):
            t = pairs[number - 1][0]
            if abs((t - pairs[0][0]) * 1e3 * slowdown - device_ms) > 0.01:
                fail(f"{frames_csv}: frame number {number} has device time {device_ms:.3f} ms, but that dataset frame "
                     f"is at {(t - pairs[0][0]) * 1e3 * slowdown:.3f} ms; was the bag made from {dataset} with "
                     f"--slowdown {slowdown}?")
            j = int(np.argmin(np.abs(gt_t - t)))
            if abs(gt_t[j] - t) > 0.01:
                continue  # no pose for this frame
            f.write(f"{stamp:.6f} {gt[j][1]}\n")
            written += 1
    return written


def _tum(path):
    out = []
    try:
        with open(path, encoding="utf-8") as f:
            for line in f:
                p = line.split()
                if len(p) == 8 and not line.startswith("#"):
                    out.append((float(p[0]), p[1:]))
    except OSError:
        fail(f"{path}: cannot read; the dataset needs its groundtruth.txt")
    return out


def main(argv=None):
    p = argparse.ArgumentParser(prog="rekon-realsense-gt", description=__doc__.split("\n\n")[0],
                                epilog="example: rekon-realsense-gt --dataset DIR --run OUT --out OUT/live_gt.txt; "
                                       "then rekon eval traj OUT/live_gt.txt OUT/trajectory.txt")
    p.add_argument("--dataset", required=True, help="the dataset the bag was made of")
    p.add_argument("--run", required=True, help="the rekon run --camera realsense --playback output folder")
    p.add_argument("--out", required=True, help="the TUM trajectory file to write")
    p.add_argument("--slowdown", type=int, default=1, help="the bag's --slowdown")
    a = p.parse_args(argv)
    csv = os.path.join(a.run, "realsense_frames.csv")
    if not os.path.isfile(csv):
        fail(f"{csv}: not found; give the --out folder of a rekon-realsense run")
    n = live_ground_truth(a.dataset, csv, a.out, a.slowdown)
    print(f"{a.out}: {n} poses")
    return 0


if __name__ == "__main__":
    sys.exit(main())
