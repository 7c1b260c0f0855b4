#!/usr/bin/env bash
# bench_viewer.sh's body, inside the network namespace: BIN DATASET OUT RUNS.
set -euo pipefail
bin=$1 dataset=$2 out=$3 runs=$4
port=8099
read -r -a run_args <<< "${REKON_RUN_ARGS:-}"  # e.g. "--set player.rate=1 --set player.pacing=live"

summary() {  # stats.json [state.json]
  python3 - "$@" <<'PY'
import csv, json, os, sys
s = json.load(open(sys.argv[1]))
m = s["mapper"]
line = "realtime_factor=%.3f mesh_cpu_share=%.4f mesh_bytes_per_s=%.0f" % (
    s["realtime_factor"], m.get("mesh_cpu_share", 0), m.get("mesh_bytes", 0) / max(s["wall_seconds"], 1e-9))
# Played live (player.pacing: live): the frames fused and the capture-to-pose latency.
latency_csv = os.path.join(os.path.dirname(sys.argv[1]), "player_latency.csv")
if os.path.exists(latency_csv):
    ms = sorted(float(r["latency_ms"]) for r in csv.DictReader(open(latency_csv)))
    p = s["player"]
    captured = p.get("frames_captured", 0) + p.get("frames_skipped_late", 0)
    line += " fused=%d/%d latency_ms_p50=%.1f latency_ms_p95=%.1f" % (
        m.get("frames_fused", 0), captured, ms[len(ms) // 2], ms[int(0.95 * (len(ms) - 1))])
if len(sys.argv) > 2:
    st = json.load(open(sys.argv[2]))
    line += " receive_ms_p50=%g receive_ms_p95=%g viewer_blocks=%d" % (
        st["receive_latency_ms_p50"], st["receive_latency_ms_p95"], st["blocks"])
    for c in st["clients"][:1]:
        line += " page_ms_p50=%g page_ms_p95=%g page_samples=%d page_blocks=%d page_handle_s=%.1f page_draw_s=%.1f" % (
            c.get("latency_ms_p50", -1), c.get("latency_ms_p95", -1), c.get("latency_samples", 0), c.get("blocks", -1),
            c.get("handle_ms", 0) / 1e3, c.get("draw_ms", 0) / 1e3)
        # issue 27: a block's first appearance (coarse or full), and full meshes only (-1: a page without them)
        line += " page_new_ms_p50=%g page_new_ms_p95=%g page_full_ms_p50=%g page_full_ms_p95=%g page_coarse_left=%d" % (
            c.get("latency_new_ms_p50", -1), c.get("latency_new_ms_p95", -1), c.get("latency_full_ms_p50", -1),
            c.get("latency_full_ms_p95", -1), c.get("coarse", -1))
print(line)
PY
}

# One run with a rekon-viewer (and, with "browser", a headless chromium on its
# page) started first, so that they see every change.
watched() {  # NAME [browser]
  local name=$1 viewer browser=
  "$bin/rekon-viewer" --set viewer.port=$port > "$out/$name.viewer.log" 2>&1 &
  viewer=$!
  until curl -s "http://127.0.0.1:$port/state.json" > /dev/null; do sleep 0.2; done
  if [[ ${2:-} == browser ]]; then
    rm -rf "$out/profile"
    chromium --headless=new --no-sandbox --disable-dev-shm-usage --use-angle=swiftshader --enable-unsafe-swiftshader \
      --user-data-dir="$out/profile" --window-size=1280,800 --remote-debugging-port=0 "http://127.0.0.1:$port/" \
      > "$out/$name.chromium.log" 2>&1 &
    browser=$!
    until curl -s "http://127.0.0.1:$port/state.json" | grep -q '"clients":\[{'; do sleep 0.5; done
  fi
  "$bin/rekon" run --dataset "$dataset" --out "$out/$name" "${run_args[@]}" > "$out/$name.log" 2>&1
  sleep 3  # the last blocks reach the page, and its next report the server
  curl -s "http://127.0.0.1:$port/state.json" > "$out/$name/viewer_state.json"
  if [[ ${2:-} == browser ]]; then  # the final map as a fresh browser draws it (README's picture)
    timeout 300 chromium --headless=new --no-sandbox --disable-dev-shm-usage --use-angle=swiftshader \
      --enable-unsafe-swiftshader --hide-scrollbars --user-data-dir="$out/profile_shot" --window-size=1280,800 \
      --virtual-time-budget=60000 --screenshot="$out/$name/viewer.png" "http://127.0.0.1:$port/" \
      > "$out/$name.screenshot.log" 2>&1 || true
  fi
  kill $browser $viewer; wait $browser $viewer 2> /dev/null || true
}

for ((i = 1; i <= runs; ++i)); do
  "$bin/rekon" run --dataset "$dataset" --out "$out/plain_$i" "${run_args[@]}" > "$out/plain_$i.log" 2>&1
  echo "without viewer, run $i: $(summary "$out/plain_$i/stats.json")"
  watched "viewer_$i"
  echo "with viewer, run $i: $(summary "$out/viewer_$i/stats.json" "$out/viewer_$i/viewer_state.json")"
  watched "browser_$i" browser
  echo "with viewer and browser, run $i: $(summary "$out/browser_$i/stats.json" "$out/browser_$i/viewer_state.json")"
done
