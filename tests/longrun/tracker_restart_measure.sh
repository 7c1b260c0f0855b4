#!/usr/bin/env bash
# Issue 48, item 1: the numbers of a restartable tracker. Runs rekon-player,
# rekon-tracker and rekon-optimiser by hand on DATASET at the player's
# fastest rate (acknowledged; no mapper: the tracker's recovery is what is
# measured), in a private network namespace. The tracker is killed with
# SIGKILL KILL_AFTER_S seconds after the start, its restart (same --out,
# tracker.restarted=true) killed again KILL_AFTER_S seconds later, and so on,
# once per argument; none: uninterrupted. Prints one line per restart (the
# frames the journal held, how its first frame was placed, milliseconds from
# the kill to that first pose) and the run's exit statuses, poses, ATE, and
# the uninterrupted instance's journal and archive costs (tracker_stats.json).
# Not in ctest.
#
#   tests/longrun/tracker_restart_measure.sh BIN_DIR DATASET OUT [KILL_AFTER_S ...]
#   e.g. ... build/bin /tmp/room600 /tmp/m 1.5 1.5 1.5 1.5 1.5
set -u
if [ -z "${REKON_IN_NETNS:-}" ]; then
  exec env REKON_IN_NETNS=1 "$(cd "$(dirname "$0")/../support" && pwd)/in_netns.sh" "$0" "$@"
fi
bin=$(cd "$1" && pwd) data=$2 out=$3
shift 3
rm -rf "$out"
mkdir -p "$out"
id=$$
sets=(--out "$out" --set "transport.segment=rekon_fr_trm$id" --set "mapper.store_segment=rekon_kf_trm$id"
      --set "player.wait_for=[tracker]")
"$bin/rekon-optimiser" "${sets[@]}" > "$out/optimiser.log" 2>&1 &
optimiser=$!
"$bin/rekon-tracker" "${sets[@]}" > "$out/tracker.log" 2>&1 &
tracker=$!
"$bin/rekon-player" --dataset "$data" "${sets[@]}" > "$out/player.log" 2>&1 &
player=$!
ms() { date -d "$1" +%s%3N; }
n=0
for after in "$@"; do
  sleep "$after"
  n=$((n + 1))
  kill -9 "$tracker" 2> /dev/null
  killed=$(date +%T.%3N)
  wait "$tracker" 2> /dev/null
  "$bin/rekon-tracker" "${sets[@]}" --set tracker.restarted=true > "$out/tracker_restarted$n.log" 2>&1 &
  tracker=$!
  echo "$killed" > "$out/killed$n.txt"
done
wait "$player"; p=$?
wait "$tracker"; t=$?
wait "$optimiser"; o=$?
for i in $(seq 1 "$n"); do
  log=$out/tracker_restarted$i.log
  held=$(sed -n 's/.*the journal holds .* and \([0-9]*\) tracked frames.*/\1/p' "$log")
  first=$(grep -m1 "first pose after the restart" "$log")
  at=$(echo "$first" | sed -n 's/^\[\([0-9:.]*\)\].*/\1/p')
  how=$(echo "$first" | sed -n 's/.*frame [0-9]*, \(.*\)/\1/p')
  echo "restart $i: journal held $held frames; first pose ${how:-none}; $(( $(ms "${at:-$(cat "$out/killed$i.txt")}") - $(ms "$(cat "$out/killed$i.txt")") )) ms after the kill"
done
echo "exit: player $p tracker $t optimiser $o; poses $(grep -vc '^#' "$out/trajectory.txt")"
"$bin/rekon" eval traj "$data/groundtruth.txt" "$out/trajectory.txt" | tail -1
[ "$n" = 0 ] && grep -E '"(frames|keyframes_archived|archive_ms|journal_records|journal_bytes|journal_append_ms)"' "$out/tracker_stats.json"
exit 0
