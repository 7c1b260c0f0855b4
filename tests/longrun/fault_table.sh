#!/usr/bin/env bash
# The fault and loss tables of README.md ("Faults"), measured again: rekon run
# on DATASET uninterrupted twice, with the mapper and with the optimiser
# killed (SIGKILL, tests/faults/kill_during_run.sh, once the keyframe store
# holds KILL_AT KF keyframes; the launcher restarts them) and with 1 % and 5 %
# of received messages dropped (lcm.drop_fraction). Each run in its own
# network namespace (tests/support/in_netns.sh), one after the other.
#
#   tests/longrun/fault_table.sh OUT DATASET [REFERENCE_MESH] [BIN_DIR]
#
# Columns: ATE against DATASET/groundtruth.txt; CORR against REFERENCE_MESH
# (default DATASET/mesh_gt.ply when present, else left out), the mesh moved by
# its trajectory's ATE alignment; the trajectory (ATE) and mesh (CORR, moved
# by the alignment of its trajectory onto run 1's) against uninterrupted run
# 1; frames the tracker handled / the mapper fused; loop closures accepted by
# the tracker / kept by the optimiser. Not in ctest: the 600-frame room takes
# about 4 minutes on 2 cores, 7scenes_loop_1000 about 4 minutes more.
# RUNS="clean1 clean2 mapper optimiser loss1 loss5" (default) picks rows;
# KILL_AT (default 12) sets when a service is killed.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:?usage: fault_table.sh OUT DATASET [REFERENCE_MESH] [BIN_DIR]}
dataset=$(cd "${2:?usage: fault_table.sh OUT DATASET [REFERENCE_MESH] [BIN_DIR]}" && pwd)
reference=${3:-}
[ -z "$reference" ] && [ -f "$dataset/mesh_gt.ply" ] && reference=$dataset/mesh_gt.ply
bin=$(cd "${4:-$here/../../build/bin}" && pwd)
netns=$here/../support/in_netns.sh
kill_at=${KILL_AT:-12}
runs=${RUNS:-clean1 clean2 mapper optimiser loss1 loss5}
mkdir -p "$out"
out=$(cd "$out" && pwd)
results=$out/results.md

lastValue() { tail -1 | tr ' ' '\n' | sed -n "s/^$1=//p"; }
mm() { awk -v v="$1" 'BEGIN { printf "%.3f", 1000 * v }'; }
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

echo "# tests/longrun/fault_table.sh $dataset, $(date -u +%Y-%m-%d), $(git -C "$here" rev-parse --short HEAD 2>/dev/null || echo '?'), $(nproc) cores" |
  tee -a "$results"
row "run | ATE mm | CORR mm | trajectory vs run 1 (ATE mm) | mesh vs run 1 (CORR mm) | frames tracked / fused | loop closures accepted / kept | notes"

for name in $runs; do
  run=$out/$name
  rm -rf "$run"
  note="" rc=0
  case $name in
    clean*) "$netns" "$bin/rekon" run --dataset "$dataset" --out "$run" > "$out/$name.out" 2>&1 || rc=$? ;;
    mapper | optimiser)
      "$netns" "$here/../faults/kill_during_run.sh" "$bin" "$name" "$kill_at" "$run" --dataset "$dataset" \
        > "$out/$name.out" 2>&1 || rc=$?
      note=$(grep -o "killed rekon-.*" "$out/$name.out" || echo "not killed: the run ended first") ;;
    loss1) "$netns" "$bin/rekon" run --dataset "$dataset" --out "$run" --set lcm.drop_fraction=0.01 > "$out/$name.out" 2>&1 || rc=$? ;;
    loss5) "$netns" "$bin/rekon" run --dataset "$dataset" --out "$run" --set lcm.drop_fraction=0.05 > "$out/$name.out" 2>&1 || rc=$? ;;
    *) echo "unknown run $name" >&2; exit 2 ;;
  esac
  [ "$rc" = 0 ] || note="$note; rekon run exited $rc ($out/$name.out)"
  ate=$(mm "$("$bin/rekon" eval traj "$dataset/groundtruth.txt" "$run/trajectory.txt" | lastValue ate_rmse_m)")
  corr=""
  [ -n "$reference" ] && corr=$(mm "$("$bin/rekon" eval surface "$run/mesh.ply" "$reference" \
    --est-trajectory "$run/trajectory.txt" --gt-trajectory "$dataset/groundtruth.txt" | lastValue corr_m)")
  vs_traj="" vs_mesh=""
  if [ "$name" != clean1 ] && [ -f "$out/clean1/trajectory.txt" ]; then
    vs_traj=$(mm "$("$bin/rekon" eval traj "$out/clean1/trajectory.txt" "$run/trajectory.txt" | lastValue ate_rmse_m)")
    vs_mesh=$(mm "$("$bin/rekon" eval surface "$run/mesh.ply" "$out/clean1/mesh.ply" \
      --est-trajectory "$run/trajectory.txt" --gt-trajectory "$out/clean1/trajectory.txt" | lastValue corr_m)")
  fi
  restarts=$(stat "$run/stats.json" restarts)
  [ "$restarts" != "{}" ] && [ "$restarts" != "-" ] && note="$note restarts $restarts"
  row "$name | $ate | $corr | $vs_traj | $vs_mesh |" \
    "$(stat "$run/stats.json" tracker.frames) / $(stat "$run/stats.json" mapper.frames_fused) |" \
    "$(stat "$run/stats.json" tracker.loop_closures_accepted) / $(stat "$run/stats.json" optimiser.loop_closures) | $note"
done
