#!/usr/bin/env bash
# measure_goals.sh DATASET OUT [FRAMES]: issue 46's goals on a dataset with
# ground truth, each run inside a private network namespace
# (tests/support/in_netns.sh), one after the other:
#   1. DATASET as a RealSense .bag (rekon-realsense-write: Intel's SDK records it)
#      and as a TUM folder: rekon run --camera realsense --playback against
#      rekon run --dataset; ATE of both (rekon eval traj), CORR of both when
#      DATASET has mesh_gt.ply (rekon eval surface), the source's counts;
#   2. capture to pose at 30 Hz on the same frames: rekon-realsense (the bag)
#      against rekon-camera (the same frames through libfreenect's fakenect,
#      rekon-fakenect-write; its depth is the Kinect's 11-bit disparity): the
#      latency_ms_p50/p95 each source measured (tracker's pose back), and
#      rekon-realsense once more with its frames inline on LCM
#      (transport.mode lcm) instead of the shared-memory frame ring;
#   3. where rekon-realsense's share of it goes (realsense_frames.csv and
#      realsense_latency.csv of the first run): the SDK's delivery, align,
#      the sending, publish to pose.
# Prints one line per number; everything stays in OUT. The machine's load
# average is printed before and after: these latencies depend on it.
set -euo pipefail
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
data="$(cd "$1" && pwd)"; out="$2"; frames="${3:-0}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
bin="$root/build/bin"; netns="$root/tests/support/in_netns.sh"
mkdir -p "$out"; out="$(cd "$out" && pwd)"
py="${REKON_VENV:-$root/.venv}/bin/python"
json() { "$py" -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }
limit=(); [ "$frames" -gt 0 ] && limit=(--set "player.max_frames=$frames")

[ -f "$out/data.bag" ] || "$bin/rekon-realsense-write" --dataset "$data" --out "$out/data.bag" --frames "$frames"
"$netns" "$bin/rekon" run --dataset "$data" --out "$out/files" --force "${limit[@]}" >"$out/files.txt" 2>&1
"$netns" "$bin/rekon" run --camera realsense --playback "$out/data.bag" --out "$out/rs" --force >"$out/rs.txt" 2>&1
"$bin/rekon-realsense-gt" --dataset "$data" --run "$out/rs" --out "$out/rs/live_gt.txt" >/dev/null
ate_files=$("$bin/rekon" eval traj "$data/groundtruth.txt" "$out/files/trajectory.txt" --json | json /dev/stdin "d['ate_rmse_m']")
ate_rs=$("$bin/rekon" eval traj "$out/rs/live_gt.txt" "$out/rs/trajectory.txt" --json | json /dev/stdin "d['ate_rmse_m']")
echo "ATE files ${ate_files} m, realsense playback ${ate_rs} m, ratio $("$py" -c "print(round($ate_rs/$ate_files, 3))")"
echo "realsense: $(json "$out/rs/realsense_stats.json" "{k: d[k] for k in ('frames_captured','frames_sent','frames_dropped','frames_skipped_late','latency_ms_p50','latency_ms_p95')}")"
echo "tracker (realsense run): $(json "$out/rs/stats.json" "(d['tracker']['frames'], d['tracker']['lost_frames'])") (frames, lost)"
if [ -f "$data/mesh_gt.ply" ]; then
  corr() { "$bin/rekon" eval surface "$1/mesh.ply" "$data/mesh_gt.ply" --est-trajectory "$1/trajectory.txt" --gt-trajectory "$2" --json | json /dev/stdin "d['corr_m']"; }
  echo "CORR files $(corr "$out/files" "$data/groundtruth.txt") m, realsense playback $(corr "$out/rs" "$out/rs/live_gt.txt") m"
fi

# Capture to pose through rekon-camera on the same frames (fakenect at 30 Hz).
fk="$out/fakenect"
[ -d "$fk" ] || "$bin/rekon-fakenect-write" --dataset "$data" --out "$fk" --frames "$frames" >/dev/null
FAKENECT_PATH="$fk" LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect "$netns" "$bin/rekon" run --camera freenect \
  --calibration "$fk/camera.yaml" --out "$out/camera" --force >"$out/camera.txt" 2>&1
"$netns" "$bin/rekon" run --camera realsense --playback "$out/data.bag" --out "$out/rs_lcm" --force \
  --set transport.mode=lcm >"$out/rs_lcm.txt" 2>&1
p50_p95="(round(d['latency_ms_p50'],1), round(d['latency_ms_p95'],1), d['frames_sent'], d.get('transport','lcm'))"
echo "capture to pose (p50 ms, p95 ms, frames sent, transport): realsense $(json "$out/rs/realsense_stats.json" "$p50_p95"), camera $(json "$out/camera/camera_stats.json" "$p50_p95"), realsense inline $(json "$out/rs_lcm/realsense_stats.json" "$p50_p95")"
"$py" - "$out/rs" <<'EOF'
import csv, sys
import numpy as np
run = sys.argv[1]
frames = {r["frame_id"]: r for r in csv.DictReader(open(f"{run}/realsense_frames.csv"))}
rows = [(frames[r["frame_id"]], r) for r in csv.DictReader(open(f"{run}/realsense_latency.csv"))]
def line(name, values):
    return f"{name} {np.percentile(values, 50):.1f}/{np.percentile(values, 95):.1f}"
print("realsense stages p50/p95 ms:", ", ".join([
    line("device stamp to SDK delivery", [float(f["delivery_ms"]) for f, _ in rows]),
    line("align and copies", [float(f["align_ms"]) for f, _ in rows]),
    line("send (ring or encode, publish)", [float(l["send_ms"]) for _, l in rows]),
    line("capture to sent", [float(l["sent_ms"]) for _, l in rows]),
    line("sent to pose", [float(l["latency_ms"]) - float(l["sent_ms"]) for _, l in rows])]))
EOF
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
