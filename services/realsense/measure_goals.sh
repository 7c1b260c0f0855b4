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
#      latency_ms_p50/p95 each source measured (tracker's pose back).
# Prints one line per number; everything stays in OUT.
set -euo pipefail
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
echo "capture to pose p50/p95 ms: realsense $(json "$out/rs/realsense_stats.json" "(round(d['latency_ms_p50'],1), round(d['latency_ms_p95'],1))"), camera $(json "$out/camera/camera_stats.json" "(round(d['latency_ms_p50'],1), round(d['latency_ms_p95'],1), d['frames_sent'])")"
