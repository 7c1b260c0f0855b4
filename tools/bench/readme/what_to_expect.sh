#!/usr/bin/env bash
# The numbers of README.md's "What to expect" table that a run gives, made
# anew: runs DATASET (default ../shared/data/7scenes_loop_1000) RUNS times
# (default 3) one after the other with the default config, then prints, per
# run and as the range over runs, the realtime factor (stats.json), the ATE
# (rekon eval traj against the dataset's groundtruth.txt) and each service's
# peak RSS (stats.json's peak_rss_mb), as the markdown the README shows.
#   tools/bench/readme/what_to_expect.sh [DATASET] [RUNS]
# Runs in a private network namespace (tests/support/in_netns.sh): loopback only.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
bin=${REKON_BIN:-$root/build/bin}
dataset=$(realpath "${1:-$root/../shared/data/7scenes_loop_1000}")
runs=${2:-3}
[[ -x $bin/rekon ]] || { echo "$bin/rekon is missing: build first (tools/rekon setup)" >&2; exit 1; }
[[ -f $dataset/groundtruth.txt ]] || { echo "$dataset has no groundtruth.txt: give a dataset with ground truth" >&2; exit 1; }
if [[ -z ${REKON_IN_NETNS:-} ]]; then exec env REKON_IN_NETNS=1 "$root/tests/support/in_netns.sh" "$0" "$dataset" "$runs"; fi
out=$(mktemp -d /tmp/rekon_what_to_expect.XXXXXX)
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg)" >&2
for i in $(seq 1 "$runs"); do
  echo "run $i of $runs into $out/run$i" >&2
  "$bin/rekon" run --dataset "$dataset" --out "$out/run$i" > "$out/run$i.log" 2>&1 || { tail -5 "$out/run$i.log" >&2; exit 1; }
  "$bin/rekon" eval traj "$dataset/groundtruth.txt" "$out/run$i/trajectory.txt" --json > "$out/run$i/ate.json"
done
python3 - "$out" "$runs" "$(basename "$dataset")" <<'PY'
import json, sys
out, runs, name = sys.argv[1], int(sys.argv[2]), sys.argv[3]
rows = []
for i in range(1, runs + 1):
    stats = json.load(open(f"{out}/run{i}/stats.json"))
    ate = json.load(open(f"{out}/run{i}/ate.json"))["ate_rmse_m"]
    rss = {s: stats[s]["peak_rss_mb"] for s in ("tracker", "optimiser", "mapper", "player") if s in stats}
    rows.append((stats["realtime_factor"], ate, rss))
    print(f"run {i}: realtime_factor {stats['realtime_factor']:.2f}, ATE {100 * ate:.2f} cm, peak RSS "
          + ", ".join(f"{s} {v:.0f} MiB" for s, v in rss.items()))
span = lambda vals, f: f.format(min(vals)) if f.format(min(vals)) == f.format(max(vals)) else f.format(min(vals)) + "-" + f.format(max(vals))
print()
print(f"| {name}, {runs} runs | `realtime_factor` {span([r[0] for r in rows], '{:.2f}')}, "
      f"ATE {span([100 * r[1] for r in rows], '{:.2f}')} cm |")
print(f"| peak memory per service, {name} | " + ", ".join(
    f"{s} {span([r[2][s] for r in rows], '{:.0f}')}" for s in rows[0][2]) + " MiB |")
PY
