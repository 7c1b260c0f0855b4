#!/usr/bin/env bash
# The long run of issue 9 (part 6): the synthetic corridor walked LAPS times
# (2 laps = 10 325 frames, 3 = 15 808) through the whole pipeline (rekon run:
# player, tracker, optimiser, mapper) at the default config; every service's
# memory is sampled once a second and the store's usage every 10 s, then
# summarised per 1000 frames with plots (summarize.py). Played live at 30 Hz
# with `--set player.rate=1 --set player.pacing=live` (the fused share and
# the per-minute capture-to-pose latency are then summarised too). STORE_MB=256 makes the keyframe
# store far smaller than the run's keyframes, so most of them spill to disk.
# Not part of ctest: it takes tens of minutes (the short version is
# tests/store, KeyframeStoreSpill.ARestartedMapper...).
#
#   [STORE_MB=256] tests/longrun/run_corridor.sh OUT [LAPS] [BIN_DIR] [--set key=value ...]
#
# No limit is raised: the stall near frame 8 700 of earlier runs (which
# needed max_queued_frames 300) was the mapper counting every frame the player
# sent again as one more queued frame (fixed; services/mapper/src/store/README.md).
# OUT/corridor_<LAPS>laps is generated unless present (0.73 MB of PNGs a
# frame at 640x480: 7.5 GB for 2 laps; checked against df first).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:?usage: run_corridor.sh OUT [LAPS] [BIN_DIR] [--set key=value ...]}
laps=${2:-2}
bin=$(cd "${3:-$here/../../build/bin}" && pwd)
shift $(( $# < 3 ? $# : 3 ))
store_mb=${STORE_MB:-}
segment=rekon_longrun_$$
data=$out/corridor_${laps}laps
run=$out/run_${laps}laps
mkdir -p "$out"
# The corridor's laps: 4 841 frames, then 5 484 each (rekon synth --scene corridor).
first_lap=4841 lap=5484
if [ ! -f "$data/rgb.txt" ]; then
  frames=$(( first_lap + (laps - 1) * lap ))
  need_kb=$(( frames * 800 ))
  avail_kb=$(df -Pk "$out" | awk 'NR==2 {print $4}')
  if [ "$avail_kb" -lt $(( need_kb + 2 * 1024 * 1024 )) ]; then
    echo "run_corridor.sh: $out has $(( avail_kb / 1024 )) MiB free; $laps laps need about $(( need_kb / 1024 )) MiB plus 2 GiB" >&2
    exit 1
  fi
  "$bin/rekon" synth --scene corridor --laps "$laps" --out "$data"
fi
rm -rf "$run"
mkdir -p "$run"
python3 "$here/sample_memory.py" "$bin" "$segment" "$run" &
sampler=$!
trap 'kill $sampler 2>/dev/null || true' EXIT
start=$(date +%s)
status=0
# Every setting is the default but the store's name (for the sampler) and,
# with STORE_MB, its size (smaller than the run's keyframes: most spill).
store_sets=(--set mapper.store_segment="$segment")
[ -n "$store_mb" ] && store_sets+=(--set mapper.store_mb="$store_mb" --set mapper.store_spill_dir="$run/keyframe_spill")
"$here/../support/in_netns.sh" "$bin/rekon" run --dataset "$data" --out "$run" "${store_sets[@]}" "$@" || status=$?
echo "rekon run exited $status after $(( $(date +%s) - start )) s"
kill $sampler 2>/dev/null || true
python3 "$here/summarize.py" "$run" "$first_lap" "$lap"
exit $status
