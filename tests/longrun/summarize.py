#!/usr/bin/env python3
"""Summarises a long run (run_corridor.sh): every service's RSS, the mapper's
voxel blocks (total and active) and the keyframe store (in shared memory and
spilled) each 1000 frames, from memory.csv, store.csv and the mapper's
progress lines; the peak of all services' RSS together; and for a live run
(player.pacing: live) the capture-to-pose latency per minute of capture
(player_latency.csv) and the share of frames fused; issue 26's flat ratios of
KF integration and correction rounds; and plots into RUN_DIR (memory.svg,
fps.svg, mapper.svg, latency.svg for a live run). Usage: summarize.py RUN_DIR
[FIRST_LAP_FRAMES LAP_FRAMES] (the corridor's laps, which run_corridor.sh passes;
without them no per-lap ratios)"""
import bisect
import csv
import datetime
import json
import os
import re
import sys

import svg_plot

run = sys.argv[1]
LAP1, LAP = (int(sys.argv[2]), int(sys.argv[3])) if len(sys.argv) > 3 else (0, 0)
kappa = 20
try:
    for line in open(os.path.join(run, "config.yaml")):
        m = re.match(r"\s+kappa:\s*(\d+)", line)
        if m:
            kappa = int(m.group(1))
except OSError:
    pass

# Mapper progress: (unix time, frames fused, blocks, active blocks).
progress = []
pattern = re.compile(r"^\[((?:[\d-]+ )?[\d:.]+)\].*mapper: (\d+) KF keyframes so far.*?(?:frames (\d+) blocks (\d+) active (\d+).*)?$")
# Since 2026-12-01: "mapper: F frames fused into K KF keyframes, ..." (no block counts).
fused_pattern = re.compile(r"^\[((?:[\d-]+ )?[\d:.]+)\].*mapper: (\d+) frames fused into (\d+) KF keyframes")
# Log lines carry the time of day only: the date is the run's (from the first memory sample).
with open(os.path.join(run, "memory.csv")) as f:
    next(f)
    first_sample = float(next(f).split(",")[0])
run_date = datetime.datetime.fromtimestamp(first_sample).strftime("%Y-%m-%d")
for line in open(os.path.join(run, "mapper.log"), errors="replace"):
    m = pattern.match(line.strip())
    fused = None if m else fused_pattern.match(line.strip())
    if not m and not fused:
        continue
    stamp_text = (m or fused).group(1)
    stamp = stamp_text if " " in stamp_text else run_date + " " + stamp_text
    t = datetime.datetime.strptime(stamp, "%Y-%m-%d %H:%M:%S.%f").timestamp()
    if fused:
        progress.append((t, int(fused.group(2)), None, None))
        continue
    frames = int(m.group(3)) if m.group(3) else int(m.group(2)) * kappa
    blocks = int(m.group(4)) if m.group(4) else None
    active = int(m.group(5)) if m.group(5) else None
    progress.append((t, frames, blocks, active))

memory = {}  # service -> sorted [(t, rss, anon, shmem)]
with open(os.path.join(run, "memory.csv")) as f:
    for r in csv.DictReader(f):
        memory.setdefault(r["service"], []).append(
            (float(r["unix_time"]), float(r["rss_mb"]), float(r["anon_mb"]), float(r["shmem_mb"])))
store = []
try:
    with open(os.path.join(run, "store.csv")) as f:
        store = [(float(r["unix_time"]), r) for r in csv.DictReader(f)]
except OSError:
    pass


def at(series, t):
    """The sample nearest before t (or the first)."""
    keys = [s[0] for s in series]
    i = max(0, bisect.bisect_right(keys, t) - 1)
    return series[i] if series else None


services = [s for s in ("player", "tracker", "optimiser", "mapper") if s in memory]
print(f"run {run}: {len(progress)} mapper progress lines, memory samples: " +
      ", ".join(f"{s} {len(memory[s])}" for s in services))
header = ["frames", "s"] + [f"{s}_rss_mb" for s in services] + ["mapper_anon_mb", "mapper_shm_mb", "blocks", "active",
                                                                  "store_shm", "store_disk", "spilled_mib"]
print(" ".join(header))
t0 = min(s[0][0] for s in memory.values()) if memory else 0
next_mark = 0
rows = []
for n, (t, frames, blocks, active) in enumerate(progress):
    if frames < next_mark and n != len(progress) - 1:  # every 1000 frames, and the last line
        continue
    next_mark = (frames // 1000 + 1) * 1000
    row = [str(frames), f"{t - t0:.0f}"]
    for s in services:
        sample = at(memory[s], t)
        row.append(f"{sample[1]:.0f}" if sample else "-")
    m = at(memory.get("mapper", []), t)
    row += [f"{m[2]:.0f}" if m else "-", f"{m[3]:.0f}" if m else "-",
            str(blocks) if blocks is not None else "-", str(active) if active is not None else "-"]
    st = at(store, t)
    row += [st[1]["resident"], st[1]["spilled"], st[1]["spilled_mib"]] if st else ["-", "-", "-"]
    rows.append(row)
    print(" ".join(row))
for s in services:
    peak = max(x[1] for x in memory[s])
    print(f"peak RSS {s}: {peak:.0f} MB")
# All services together: the samples of one sweep (once a second), in the
# sweeps that caught every service.
sweeps = {}
for s in services:
    for t, rss, _, _ in memory[s]:
        sweeps.setdefault(round(t), {})[s] = rss
by_sweep = sorted((t, v) for t, v in sweeps.items() if len(v) == len(services))
if by_sweep:
    print(f"peak RSS of all services together: {max(sum(v.values()) for _, v in by_sweep):.0f} MB")


def frames_at(t):
    return at(progress, t)[1] if progress else 0


# The corridor's laps (given by run_corridor.sh): each service's RSS when
# lap 1 ends against its highest in the last lap while the stream lasts
# (issue 26's goal: within 1.2x). The end of the run (final pass, meshes)
# comes after and is in the peaks above.
total = progress[-1][1] if progress else 0
if LAP > 0 and total >= LAP1 + LAP:
    last_lap = LAP1 + (total - LAP1 - 1) // LAP * LAP
    for s in services:
        lap1 = [x[1] for x in memory[s] if frames_at(x[0]) <= LAP1]
        last = [x[1] for x in memory[s] if last_lap <= frames_at(x[0]) < total]
        if lap1 and last:
            print(f"RSS {s}: {lap1[-1]:.0f} MB at the end of lap 1 (frame {LAP1}), at most {max(last):.0f} MB in the "
                  f"last lap (frames {last_lap}-{total}): {max(last) / lap1[-1]:.2f}x")


def quantile(values, q):
    values = sorted(values)
    return values[min(len(values) - 1, int(q * (len(values) - 1)))] if values else float("nan")


def json_file(name):
    try:
        return json.load(open(os.path.join(run, name)))
    except (OSError, ValueError):
        return {}


# A live run (player.pacing: live, or a camera): the capture-to-pose latency
# per minute of capture (<source>_latency.csv), and the share of frames fused.
for source in ("player", "camera"):
    path = os.path.join(run, f"{source}_latency.csv")
    if not os.path.exists(path):
        continue
    minutes, per_300 = {}, {}
    with open(path) as f:
        for r in csv.DictReader(f):
            # A frame the source took late can be captured just before its start: minute 0.
            minutes.setdefault(max(0, int(float(r["captured_s"]) // 60)), []).append(float(r["latency_ms"]))
            per_300.setdefault(int(r["frame_id"]) // 300 * 300, []).append(float(r["latency_ms"]))
    svg_plot.write(os.path.join(run, "latency.svg"), "capture-to-pose latency per 300 frames", "frame", "ms",
                   {q: [(f, quantile(v, float(q[1:]) / 100)) for f, v in per_300.items()] for q in ("p50", "p95")})
    print("minute frames latency_ms_p50 latency_ms_p95")
    for minute in sorted(minutes):
        v = minutes[minute]
        print(f"{minute} {len(v)} {quantile(v, 0.5):.0f} {quantile(v, 0.95):.0f}")
    if len(minutes) > 1:
        first, last = minutes[min(minutes)], minutes[max(minutes)]
        print(f"latency p95 last minute / first minute: {quantile(last, 0.95) / quantile(first, 0.95):.2f}")
    src, mapper = json_file(f"{source}_stats.json"), json_file("mapper_stats.json")
    captured = src.get("frames_captured", 0) + src.get("frames_skipped_late", 0)
    if captured and "frames_fused" in mapper:
        print(f"frames fused: {mapper['frames_fused']} of {captured} ({100.0 * mapper['frames_fused'] / captured:.1f} %); "
              f"{source}: {src.get('frames_skipped_late')} skipped late, {src.get('frames_dropped')} dropped; "
              f"mapper: {mapper.get('frames_dropped')} dropped")


def read_rows(name):
    try:
        with open(os.path.join(run, name)) as f:
            return list(csv.DictReader(f))
    except OSError:
        return []


def binned(points, width=500):
    """Mean y per `width` frames, at the bin's start."""
    bins = {}
    for x, y in points:
        bins.setdefault(int(x) // width * width, []).append(y)
    return [(b, sum(v) / len(v)) for b, v in sorted(bins.items())]


def flat_ratio(label, points):
    """Issue 26's flat goal: the mean over the last 1000 frames against frames 1000-2000."""
    if not points:
        return
    end = max(x for x, _ in points)
    early = [y for x, y in points if 1000 <= x < 2000]
    late = [y for x, y in points if x >= end - 1000]
    if early and late:
        e, l = sum(early) / len(early), sum(late) / len(late)
        print(f"{label}: {e:.1f} ms over frames 1000-2000, {l:.1f} ms over the last 1000 ({l / e:.2f}x)")


# Plots against frames: memory (memory.svg), throughput (fps.svg), and the
# mapper's KF integrations and correction rounds (mapper.svg).

memory_series = {s: [(frames_at(t), v[s]) for t, v in by_sweep] for s in services}
memory_series["all services"] = [(frames_at(t), sum(v.values())) for t, v in by_sweep]
svg_plot.write(os.path.join(run, "memory.svg"), "RSS per service", "frames fused", "MB", memory_series)
svg_plot.write(os.path.join(run, "fps.svg"), "frames fused per second", "frames fused", "frames/s",
               {"mapper": [(b[1], (b[1] - a[1]) / (b[0] - a[0])) for a, b in zip(progress, progress[1:]) if b[0] > a[0]]})
integrations = [(int(r["frame_id"]), float(r["integrate_ms"])) for r in read_rows("mapper_timing.csv")
                if float(r["integrate_ms"]) > 0]
rounds = [(int(r["frames_fused"]), float(r["ms"])) for r in read_rows("mapper_reintegration.csv")
          if r.get("frames_fused") and r["final_pass"] == "0" and int(r["keyframes_reintegrated"]) > 0]
flat_ratio("KF integration", integrations)
flat_ratio("correction round", rounds)
svg_plot.write(os.path.join(run, "mapper.svg"), "mapper: mean per 500 frames", "frame", "ms",
               {"KF integration": binned(integrations), "correction round": binned(rounds)})
stats = json_file("stats.json")
print(f"stats.json: frames {stats.get('frames')} wall_seconds {stats.get('wall_seconds')}" if stats else "no stats.json")
