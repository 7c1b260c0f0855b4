#!/usr/bin/env bash
# The results tables of services/mapper/README.md, measured again.
#
#   tests/longrun/mapper_results.sh OUT [room|7scenes|all] [BIN_DIR] [DATA_DIR]
#
# room: `rekon synth --scene room --frames 600 --drift 0.03,1.5` (generated
# into OUT/room unless present), reference its mesh_gt.ply. 7scenes:
# DATA_DIR/7scenes_loop_1000 (default ../shared/data), reference every raw
# frame fused at its ground truth by `rekon fuse` (the paper's reference).
# Runs, all at the default config (kappa 20, m 10, streaming radius 4 m):
#   (a)  rekon run: tracker + optimiser, correction on (consecutive)
#   (b)  the same run's mesh_uncorrected.ply (every KF keyframe at the pose
#        of its first integration, never corrected: a reintegration=none run
#        of the same stream)
#   (c)  rekon-replay, ground-truth poses, kappa 20
#   (c1) rekon fuse at the ground truth, every frame (kappa 1); room only
#   (d)  rekon fuse of every frame at (a)'s final trajectory.txt and at its
#        odometry.txt: what the mapper could reach with the run's own poses
#   drift (a) / (a') / (b): room only, rekon-replay of drifted_trajectory.txt
#        moved to the ground truth, consecutive / most_moved / uncorrected
# Scores: rekon eval surface (CORR / COMPL mm, cap 5 cm); a tracker run's
# meshes are first moved by the ATE alignment of its trajectory.txt
# (--est-trajectory), (a) and (b) by the same one, so that they differ only
# in the correction. Replayed and fused meshes are in the ground truth's
# frame already. Every pipeline runs
# in its own network namespace (tests/support/in_netns.sh). Prints one
# markdown row per run and writes them to OUT/results.md. Not in ctest:
# about 10 minutes for both on 2 cores.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:?usage: mapper_results.sh OUT [room|7scenes|all] [BIN_DIR] [DATA_DIR]}
which=${2:-all}
bin=$(cd "${3:-$here/../../build/bin}" && pwd)
data=${4:-$here/../../../shared/data}
netns=$here/../support/in_netns.sh
mkdir -p "$out"
out=$(cd "$out" && pwd)
results=$out/results.md

# key=value pairs of a program's last line, e.g. corr_m=... compl_m=...
lastValue() { tail -1 | tr ' ' '\n' | sed -n "s/^$1=//p"; }
mm() { awk -v v="$1" 'BEGIN { printf "%.2f", 1000 * v }'; }

surface() {  # MESH REF [EST_TRAJECTORY GT_TRAJECTORY] -> "CORR | COMPL"
  local line
  if [ $# -eq 4 ]; then line=$("$bin/rekon" eval surface "$1" "$2" --est-trajectory "$3" --gt-trajectory "$4")
  else line=$("$bin/rekon" eval surface "$1" "$2" --no-align); fi  # fused at ground-truth poses: REF's world
  echo "$(mm "$(echo "$line" | lastValue corr_m)") | $(mm "$(echo "$line" | lastValue compl_m)")"
}
ate() { mm "$("$bin/rekon" eval traj "$1" "$2" | lastValue ate_rmse_m)"; }

# A key of a stats JSON file (nested keys as a.b), or "-".
stat() {
  python3 - "$1" "$2" <<'EOF'
import json, sys
v = json.load(open(sys.argv[1]))
for k in sys.argv[2].split("."):
    v = v.get(k) if isinstance(v, dict) else None
print("-" if v is None else v)
EOF
}

row() { echo "| $* |" | tee -a "$results"; }

pipeline() {  # NAME DATASET [--set ...]
  local name=$1 dataset=$2
  shift 2
  "$netns" "$bin/rekon" run --dataset "$dataset" --out "$out/$name" "$@" > "$out/$name.out" 2>&1 ||
    { echo "rekon run $name failed: $out/$name.out" >&2; exit 1; }
}

replay() {  # NAME DATASET TRAJECTORY TARGET [mapper --set ...]
  local name=$1 dataset=$2 trajectory=$3 target=$4
  shift 4
  rm -rf "${out:?}/$name"
  mkdir -p "$out/$name"
  "$netns" bash -c '
    bin=$1 dir=$2 dataset=$3 trajectory=$4 target=$5 id=$6
    shift 6
    "$bin/rekon-mapper" --out "$dir" --set mapper.store_segment="rekon_mr_kf_$id" "$@" > "$dir/mapper.log" 2>&1 & m=$!
    "$bin/rekon-replay" --trajectory "$trajectory" --target "$target" > "$dir/replay.log" 2>&1 & r=$!
    "$bin/rekon-player" --dataset "$dataset" --set "player.wait_for=[replay,mapper]" --set transport.mode=shm \
      --set transport.segment="rekon_mr_$id" > "$dir/player.log" 2>&1; p=$?
    wait $r; rr=$?; wait $m; mm=$?
    [ "$p$rr$mm" = 000 ]' replay "$bin" "$out/$name" "$dataset" "$trajectory" "$target" "$$" "$@" ||
    { echo "replay $name failed: logs in $out/$name" >&2; exit 1; }
}

reintegrations() {  # STATS_JSON [service prefix] -> "N (final pass M)"
  echo "$(stat "$1" "${2:-}reintegrations") ($(stat "$1" "${2:-}final_pass_reintegrations"))"
}
streamed() { echo "$(stat "$1" "${2:-}streamed_out") / $(stat "$1" "${2:-}streamed_in")"; }

tracker_rows() {  # RUN_NAME DATASET REFERENCE
  local run=$out/$1 dataset=$2 reference=$3
  local loops
  loops="$(stat "$run/stats.json" tracker.loop_closures_accepted) accepted, $(stat "$run/stats.json" optimiser.loop_closures) kept"
  row "(a) correction, consecutive | tracker + optimiser (ATE $(ate "$dataset/groundtruth.txt" "$run/trajectory.txt") mm; loop closures $loops) |" \
    "$(surface "$run/mesh.ply" "$reference" "$run/trajectory.txt" "$dataset/groundtruth.txt") |" \
    "$(reintegrations "$run/stats.json" mapper.) | $(streamed "$run/stats.json" mapper.)"
  row "(b) no correction (mesh_uncorrected.ply of (a)) | same run; odometry alone ATE $(ate "$dataset/groundtruth.txt" "$run/odometry.txt") mm |" \
    "$(surface "$run/mesh_uncorrected.ply" "$reference" "$run/trajectory.txt" "$dataset/groundtruth.txt") | 0 |"
  local poses
  for poses in trajectory odometry; do
    "$bin/rekon" fuse --dataset "$dataset" --poses "$run/$poses.txt" --out "$run/fuse_$poses.ply" > /dev/null
    row "(d) every raw frame, kappa 1 | rekon fuse at (a)'s $poses.txt |" \
      "$(surface "$run/fuse_$poses.ply" "$reference" "$run/$poses.txt" "$dataset/groundtruth.txt") | |"
  done
}

replay_row() {  # LABEL POSES RUN_NAME REFERENCE
  local run=$out/$3
  row "$1 | $2 | $(surface "$run/mesh.ply" "$4") | $(reintegrations "$run/mapper_stats.json") | $(streamed "$run/mapper_stats.json")"
}

echo "# tests/longrun/mapper_results.sh, $(date -u +%Y-%m-%d), $(git -C "$here" rev-parse --short HEAD 2>/dev/null || echo '?'), $(nproc) cores" |
  tee -a "$results"
row "run | poses | CORR | COMPL | re-integrations (final pass) | streamed out / in"

if [ "$which" = room ] || [ "$which" = all ]; then
  room=$out/room
  [ -f "$room/rgb.txt" ] || "$bin/rekon" synth --scene room --frames 600 --drift 0.03,1.5 --out "$room" > /dev/null
  row "**room** | | | | |"
  pipeline room_a "$room"
  tracker_rows room_a "$room" "$room/mesh_gt.ply"
  replay room_c "$room" "$room/groundtruth.txt" "$room/groundtruth.txt"
  replay_row "(c) ground truth, kappa 20" "rekon-replay GT -> GT" room_c "$room/mesh_gt.ply"
  "$bin/rekon" fuse --dataset "$room" --poses "$room/groundtruth.txt" --out "$out/room_c1.ply" > /dev/null
  row "(c1) ground truth, kappa 1 | rekon fuse | $(surface "$out/room_c1.ply" "$room/mesh_gt.ply") | | "
  replay room_drift_a "$room" "$room/drifted_trajectory.txt" "$room/groundtruth.txt"
  replay_row "(a) correction, consecutive" "rekon-replay drifted (3 cm/m, 1.5 deg/m) -> GT" room_drift_a "$room/mesh_gt.ply"
  replay room_drift_a2 "$room" "$room/drifted_trajectory.txt" "$room/groundtruth.txt" --set mapper.reintegration=most_moved
  replay_row "(a') correction, most_moved" "same" room_drift_a2 "$room/mesh_gt.ply"
  row "(b) no correction (mesh_uncorrected.ply of drift (a)) | same |" \
    "$(surface "$out/room_drift_a/mesh_uncorrected.ply" "$room/mesh_gt.ply") | 0 |"
fi

if [ "$which" = 7scenes ] || [ "$which" = all ]; then
  seven=$(cd "$data/7scenes_loop_1000" && pwd)
  reference=$out/7scenes_reference.ply
  [ -f "$reference" ] || "$bin/rekon" fuse --dataset "$seven" --poses "$seven/groundtruth.txt" --out "$reference" > /dev/null
  row "**7scenes_loop_1000** | | | | |"
  pipeline 7scenes_a "$seven"
  tracker_rows 7scenes_a "$seven" "$reference"
  replay 7scenes_c "$seven" "$seven/groundtruth.txt" "$seven/groundtruth.txt"
  replay_row "(c) ground truth, kappa 20" "rekon-replay GT -> GT" 7scenes_c "$reference"
fi
