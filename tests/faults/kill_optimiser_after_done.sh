#!/usr/bin/env bash
# Runs `rekon run` and kills the optimiser with SIGKILL after its done_t,
# while it lingers for the mapper (issue 25, finding 1: its done_t was taken
# for its restart's, and the run hung). To make the moment certain, the
# mapper is held stopped (SIGSTOP) from the tracker's end of stream (it
# cannot finish before the optimiser's done_t, which follows the tracker's)
# until the optimiser is killed: so the optimiser is still lingering when
# the kill lands. The mapper then goes on (SIGCONT) and meets the killed
# instance's done_t and its restart.
#
# Prints "killed rekon-optimiser ..." when the kill landed and exits with
# rekon run's status; else prints "nothing killed: WHY" and exits 125.
# usage: kill_optimiser_after_done.sh BIN_DIR OUT [rekon run options...]
set -u
bin=$1 out=$2
shift 2
mkdir -p "$out"
setsid timeout 240 "$bin/rekon" run --out "$out" "$@" > "$out/run.out" 2>&1 &
run=$!

pid_of() { sed -n "s/.*started rekon-$1 (pid \([0-9]*\)).*/\1/p" "$out/run.out" | head -1; }
# Waits (20 ms steps, 120 s at most) until FILE has a line matching REGEX.
wait_for_line() {
  for _ in $(seq 1 6000); do
    grep -q "$2" "$1" 2> /dev/null && return 0
    kill -0 "$run" 2> /dev/null || return 1
    sleep 0.02
  done
  return 1
}

why=""
if ! wait_for_line "$out/tracker.log" "end of stream after frame"; then
  why="the tracker never reached the end of the stream"
else
  mapper=$(pid_of mapper)
  kill -STOP "$mapper"
  if ! wait_for_line "$out/optimiser.log" "final graph update and done_t sent"; then
    why="the optimiser never sent its done_t"
  else
    optimiser=$(pid_of optimiser)
    kill -9 "$optimiser" && echo "killed rekon-optimiser (pid $optimiser) after its done_t"
  fi
  kill -CONT "$mapper"
fi
wait "$run"
status=$?
if [ -n "$why" ]; then
  echo "nothing killed: $why"
  exit 125
fi
exit $status
