#!/usr/bin/env bash
# The player's own floor (issue 19): how fast rekon-player alone loads,
# decodes and publishes a dataset, with no consumer to wait for (wait_for
# empty, rate max; frames into the shared-memory ring), for each
# player.decode_threads given (default "0 2"):
#   tools/bench/player/bench_player.sh DATASET [THREADS...]
# Prints one line per setting: frames/s and ms per frame (wall), and the
# player's CPU ms per frame. Runs in a private network namespace
# (tests/support/in_netns.sh): loopback only.
set -euo pipefail
if [[ $# -lt 1 ]]; then echo "usage: $0 DATASET [THREADS...]" >&2; exit 2; fi
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
bin=${REKON_BIN:-$root/build/bin}
dataset=$(realpath "$1")
shift
threads=("$@")
[[ ${#threads[@]} -gt 0 ]] || threads=(0 2)
[[ -x $bin/rekon-player ]] || { echo "$bin/rekon-player is missing: build first (tools/rekon build)" >&2; exit 1; }
if [[ -z ${REKON_IN_NETNS:-} ]]; then exec env REKON_IN_NETNS=1 "$root/tests/support/in_netns.sh" "$0" "$dataset" "${threads[@]}"; fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for t in "${threads[@]}"; do
  /usr/bin/time -f "%U %S" -o "$out/time_$t" "$bin/rekon-player" --dataset "$dataset" --out "$out/p$t" \
    --set 'player.wait_for=[]' --set transport.mode=shm --set "player.decode_threads=$t" --set log.level=warn > "$out/log_$t" 2>&1 \
    || { cat "$out/log_$t" >&2; exit 1; }
  python3 - "$out/p$t/player_stats.json" "$out/time_$t" "$t" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
user, system = map(float, open(sys.argv[2]).read().split()[-2:])
frames, wall = s["frames"], s["wall_seconds"]
print(f"decode_threads={sys.argv[3]} frames={frames} frames_per_s={frames / wall:.1f} "
      f"ms_per_frame={1e3 * wall / frames:.2f} cpu_ms_per_frame={1e3 * (user + system) / frames:.2f}")
PY
done
