#!/usr/bin/env bash
# The live viewer's cost and update latency on a dataset (issue 17):
#   tools/bench/viewer/bench_viewer.sh DATASET OUT [RUNS]
# runs `rekon run` RUNS times (default 1) each way: without the viewer, with
# a rekon-viewer listening, and with a headless chromium (software WebGL, on
# the same cores) watching its page from the start. Prints one line per run:
# realtime_factor, the mapper's mesh CPU share and bytes/s on the bus, the
# viewer's change-to-receipt latency and the page's change-to-drawn latency
# (p50/p95, ms: of every block version; page_new_*: a block's first
# appearance, coarse or full; page_full_*: full meshes only) and its own
# time; OUT/browser_N/viewer.png is a screenshot of
# the final map. REKON_RUN_ARGS goes to every `rekon run` (with
# "--set player.rate=1 --set player.pacing=live" the lines add the frames
# fused and the capture-to-pose latency p50/p95). Everything runs in a private network namespace
# (tests/support/in_netns.sh): loopback only.
set -euo pipefail
if [[ $# -lt 2 ]]; then echo "usage: $0 DATASET OUT [RUNS]" >&2; exit 2; fi
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
bin=${REKON_BIN:-$root/build/bin}
dataset=$(realpath "$1")
out=$(realpath -m "$2")
runs=${3:-1}
command -v chromium > /dev/null || { echo "chromium is missing: tools/rekon deps installs it" >&2; exit 1; }
[[ -x $bin/rekon ]] || { echo "$bin/rekon is missing: build first (tools/rekon build)" >&2; exit 1; }
mkdir -p "$out"
exec "$root/tests/support/in_netns.sh" bash "$here/watch_run.sh" "$bin" "$dataset" "$out" "$runs"
