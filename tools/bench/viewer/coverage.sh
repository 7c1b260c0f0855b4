#!/usr/bin/env bash
# How much of the map a page shows while a run goes (issue 27):
#   tools/bench/viewer/coverage.sh DATASET OUT
# starts a rekon-viewer and a headless chromium on its page (software WebGL,
# on the same cores), then `rekon run` at the dataset's recorded rate
# (player.rate=1), and prints once a second the mapper's frame and KF
# keyframes, the blocks the viewer holds and the blocks the page holds (and
# how many of those are coarse meshes); after the run, the page's latency
# from a block's change to drawn (p50/p95 ms) of first appearances and of
# full meshes. A block's latency runs from its newest change, so a block that
# waited while it kept changing looks young: the page's block count against
# the viewer's, mid-run, is the measure of what a person sees. Runs in a
# private network namespace (tests/support/in_netns.sh): loopback only.
set -euo pipefail
if [[ $# -lt 2 ]]; then echo "usage: $0 DATASET OUT" >&2; exit 2; fi
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
if [[ -z ${REKON_COVERAGE_IN_NETNS:-} ]]; then
  export REKON_COVERAGE_IN_NETNS=1
  exec "$root/tests/support/in_netns.sh" bash "$0" "$@"
fi
bin=${REKON_BIN:-$root/build/bin}
dataset=$(realpath "$1")
out=$(realpath -m "$2")
port=8098
command -v chromium > /dev/null || { echo "chromium is missing: tools/rekon deps installs it" >&2; exit 1; }
mkdir -p "$out"
"$bin/rekon-viewer" --set viewer.port=$port > "$out/viewer.log" 2>&1 &
viewer=$!
until curl -s "http://127.0.0.1:$port/state.json" > /dev/null; do sleep 0.2; done
chromium --headless=new --no-sandbox --disable-dev-shm-usage --use-angle=swiftshader --enable-unsafe-swiftshader \
  --user-data-dir="$out/profile" --window-size=1280,800 --remote-debugging-port=0 "http://127.0.0.1:$port/" \
  > "$out/chromium.log" 2>&1 &
browser=$!
until curl -s "http://127.0.0.1:$port/state.json" | grep -q '"clients":\[{'; do sleep 0.5; done

state() {  # end|tick
  curl -s "http://127.0.0.1:$port/state.json" | python3 -c '
import json, sys
s = json.load(sys.stdin)
c = (s.get("clients") or [{}])[0]
m = s["status"]["services"].get("mapper", {})
try:
    kf = json.loads(m.get("stats") or "{}").get("kf_keyframes")
except ValueError:
    kf = None
line = "frame=%s kf_keyframes=%s viewer_blocks=%d viewer_coarse=%s page_blocks=%s page_coarse=%s" % (
    m.get("last_frame"), kf, s["blocks"], s.get("coarse_blocks"), c.get("blocks"), c.get("coarse"))
if sys.argv[1] == "end":
    line += " page_new_ms_p50=%s page_new_ms_p95=%s page_full_ms_p50=%s page_full_ms_p95=%s" % (
        c.get("latency_new_ms_p50"), c.get("latency_new_ms_p95"), c.get("latency_full_ms_p50"), c.get("latency_full_ms_p95"))
print(line)' "$1"
}

"$bin/rekon" run --dataset "$dataset" --out "$out/run" --set player.rate=1 > "$out/run.log" 2>&1 &
run=$!
start=$SECONDS
while kill -0 $run 2> /dev/null; do
  echo "t=$((SECONDS - start))s $(state tick)"
  sleep 1
done
wait $run || echo "rekon run failed: $out/run.log" >&2
sleep 3  # the last blocks reach the page, and its next report the server
echo "after the run: $(state end)"
kill $browser $viewer
wait $browser $viewer 2> /dev/null || true
