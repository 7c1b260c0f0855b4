#!/usr/bin/env bash
# Issue 48's live goal, measured: a live scan through libfreenect's fakenect
# (the room as a Kinect recording at 30 Hz) with rekon-camera killed twice
# and rekon-tracker once (SIGKILL at fixed times; rekon run restarts them),
# against the same frames run from the dataset folder. Prints the restarts,
# the camera's counts, the poses, and the live mesh against the file run's
# and both against the room's exact surface (CORR).
#
#   tests/longrun/live_kills.sh OUT [FRAMES] [BIN_DIR]
#
# Kills at CAMERA_KILLS (default "6 14") and TRACKER_KILLS (default "10")
# seconds after the run starts. A killed camera is a new process: fakenect
# plays its recording from the start again (a real camera sends what it sees
# now), so the live run sees the room's first frames again after each
# camera restart. Not in ctest: about 2 minutes on 2 cores.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:?usage: live_kills.sh OUT [FRAMES] [BIN_DIR]}
frames=${2:-600}
bin=$(cd "${3:-$here/../../build/bin}" && pwd)
netns=$here/../support/in_netns.sh
mkdir -p "$out"
out=$(cd "$out" && pwd)

[ -f "$out/room/groundtruth.txt" ] || "$bin/rekon" synth --scene room --frames "$frames" --out "$out/room" > "$out/synth.log"
[ -f "$out/fakenect/INDEX.txt" ] || "$bin/rekon-fakenect-write" --dataset "$out/room" --out "$out/fakenect" > /dev/null
"$netns" "$bin/rekon" run --dataset "$out/room" --out "$out/files" --force > "$out/files.txt" 2>&1

# The live run, with its kills: the newest pid of each service from rekon run's log.
pidOf() { sed -n "s/.*started rekon-$1 (pid \([0-9]*\)).*/\1/p" "$out/live.txt" | tail -1; }
FAKENECT_PATH="$out/fakenect" LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect \
  "$netns" "$bin/rekon" run --camera freenect --calibration "$out/fakenect/camera.yaml" --out "$out/live" --force \
  > "$out/live.txt" 2>&1 &
run=$!
kills=$(for t in ${CAMERA_KILLS:-6 14}; do echo "$t camera"; done; for t in ${TRACKER_KILLS:-10}; do echo "$t tracker"; done)
start=$(date +%s.%N)
while read -r at service; do
  sleep "$(echo "$start + $at - $(date +%s.%N)" | bc | sed 's/^-.*/0/')"
  pid=$(pidOf "$service")
  if [ -n "$pid" ] && kill -9 "$pid" 2> /dev/null; then echo "killed rekon-$service (pid $pid) at $at s"; fi
done < <(echo "$kills" | sort -n)
rc=0
wait "$run" || rc=$?

json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }
echo "live run: exit $rc, restarts $(json "$out/live/stats.json" "d.get('restarts')")"
echo "camera (last instance): $(json "$out/live/camera_stats.json" "{k: d.get(k) for k in ('restarted_at_frame', 'frames_captured', 'frames_sent', 'frames_dropped', 'frames_skipped_late', 'outages')}")"
echo "poses: files $(grep -vc '^#' "$out/files/trajectory.txt"), live $(grep -vc '^#' "$out/live/trajectory.txt")"
# Both runs start at the recording's first frame, so both maps are in that
# camera's frame (the live trajectory is on this computer's clock and cannot
# be aligned by time): compared as they are, and each moved into the ground
# truth's world by the file run's alignment.
echo "live mesh vs the file run's: $("$bin/rekon" eval surface "$out/live/mesh.ply" "$out/files/mesh.ply" --no-align | tail -1)"
for run in files live; do
  echo "$run mesh vs mesh_gt: $("$bin/rekon" eval surface "$out/$run/mesh.ply" "$out/room/mesh_gt.ply" \
    --est-trajectory "$out/files/trajectory.txt" --gt-trajectory "$out/room/groundtruth.txt" | tail -1)"
done
exit "$rc"
