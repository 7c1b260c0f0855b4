#!/usr/bin/env bash
# Issue 25's long-run kill test: a scan of at least 5 000 frames through the
# tracker and the optimiser (no mapper: the optimiser's recovery is what is
# measured), once uninterrupted and once with the optimiser killed (SIGKILL)
# in the last quarter of the stream. rekon run restarts it; the new instance
# rebuilds its graph from its journal (optimiser_journal.rkj) and asks the
# tracker only for what came after, batch by batch. Checks, and prints as one
# markdown row per run:
#   - the restart came in the last quarter (its journal held >= 75 % of the frames);
#   - the rebuilt graph holds every keyframe and constraint the tracker
#     published (optimiser_stats.json against tracker_stats.json);
#   - the trajectory has every tracked frame, and its ATE against the ground
#     truth and against the uninterrupted run.
# Not in ctest: FRAMES (default 6 000) of the 2-lap corridor, with its
# revisits (generated into OUT unless DATASET is given; about 5 GB of PNGs).
#
#   [REUSE_CLEAN=1] [KILL_AT=85] tests/longrun/optimiser_restart_long.sh OUT [DATASET] [BIN_DIR]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:?usage: optimiser_restart_long.sh OUT [DATASET] [BIN_DIR]}
mkdir -p "$out"
out=$(cd "$out" && pwd)
data=${2:-$out/corridor_2laps}
bin=$(cd "${3:-$here/../../build/bin}" && pwd)
netns=$here/../support/in_netns.sh
[ -f "$data/rgb.txt" ] || "$bin/rekon" synth --scene corridor --laps 2 --frames "${FRAMES:-6000}" --out "$data"
data=$(cd "$data" && pwd)
frames=$(grep -vc '^#' "$data/rgb.txt")
sets=(--set 'run.services=[player, tracker, optimiser]' --set 'player.wait_for=[tracker]')

run_clean() {
  local dir=$out/uninterrupted start
  rm -rf "$dir"
  start=$(date +%s)
  "$netns" "$bin/rekon" run --dataset "$data" --out "$dir" "${sets[@]}" > "$out/uninterrupted.out" 2>&1
  echo $(( $(date +%s) - start ))
}

# Kills the optimiser once the player's progress line says KILL_AT percent
# (default 85) of the frames are sent: the last quarter of the stream.
run_killed() {
  local dir=$out/killed
  rm -rf "$dir"
  mkdir -p "$dir"
  "$netns" "$bin/rekon" run --dataset "$data" --out "$dir" "${sets[@]}" > "$out/killed.out" 2>&1 &
  local run=$! pid="" sent=0
  while kill -0 "$run" 2> /dev/null; do
    sent=$(sed -n 's/.*frame \([0-9]*\)\/[0-9]* (.*/\1/p' "$dir/player.log" 2> /dev/null | tail -1 || true)
    [ "${sent:-0}" -ge $(( frames * ${KILL_AT:-85} / 100 )) ] && break
    sleep 0.2
  done
  pid=$(sed -n 's/.*started rekon-optimiser (pid \([0-9]*\)).*/\1/p' "$out/killed.out" | tail -1)
  kill -9 "$pid" && echo "killed rekon-optimiser (pid $pid) at frame ${sent:-?} of $frames" >&2
  wait "$run"
}

stat() { python3 -c "import json,sys; print(json.load(open(sys.argv[1])).get(sys.argv[2], -1))" "$1" "$2"; }
ate() { "$bin/rekon" eval traj "$1" "$2" 2> /dev/null | sed -n 's/.*ate_rmse_m=\([0-9.e-]*\).*/\1/p'; }

# REUSE_CLEAN=1 keeps an uninterrupted run already in OUT.
if [ -n "${REUSE_CLEAN:-}" ] && [ -f "$out/uninterrupted/stats.json" ]; then
  echo "uninterrupted: kept from an earlier call"
else
  echo "uninterrupted: $(run_clean) s"
fi
run_killed
replayed=$(sed -n 's/.*rebuilt from optimiser_journal.rkj: [0-9]* keyframes, [0-9]* constraints, \([0-9]*\) tracked frames.*/\1/p' \
  "$out/killed/optimiser.log" | tail -1)
grep -h -e "this optimiser is a restart" -e "graph updates continue after version" "$out/killed/optimiser.log" | sed 's/^.*\] //' >&2 || true
echo "| run | frames | restart at frame | tracker keyframes / constraints | optimiser keyframes / constraints (kept + removed) | trajectory frames | ATE mm | vs uninterrupted ATE mm |"
echo "|---|---|---|---|---|---|---|---|"
status=0
for r in uninterrupted killed; do
  d=$out/$r
  tk=$(stat "$d/tracker_stats.json" keyframes)
  tc=$(( $(stat "$d/tracker_stats.json" keyframes) - 1 + $(stat "$d/tracker_stats.json" loop_closures_accepted) ))
  ok=$(stat "$d/optimiser_stats.json" keyframes)
  oc=$(( $(stat "$d/optimiser_stats.json" constraints) + $(stat "$d/optimiser_stats.json" loop_edges_removed) ))
  tf=$(stat "$d/optimiser_stats.json" trajectory_frames)
  a=$(ate "$data/groundtruth.txt" "$d/trajectory.txt")
  v=$(ate "$out/uninterrupted/trajectory.txt" "$d/trajectory.txt")
  at=-
  [ "$r" = killed ] && at=${replayed:-none}
  echo "| $r | $frames | $at | $tk / $tc | $ok / $oc | $tf | $(python3 -c "print(round(${a:-nan}*1000,3))") | $(python3 -c "print(round(${v:-nan}*1000,3))") |"
  [ "$tk" = "$ok" ] && [ "$tc" = "$oc" ] ||
    { echo "$r: the optimiser holds $ok keyframes / $oc constraints, the tracker published $tk / $tc" >&2; status=1; }
done
if [ -z "$replayed" ] || [ "$replayed" -lt $(( frames * 3 / 4 )) ]; then
  echo "the restart did not come in the last quarter (journal of ${replayed:-no} frames of $frames); raise KILL_AT" >&2
  status=1
fi
exit $status
