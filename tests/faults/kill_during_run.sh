#!/usr/bin/env bash
# Runs `rekon run` and kills one of its services with SIGKILL mid-run: once
# the mapper's keyframe store holds MIN_KEYFRAMES KF keyframes. SERVICE "all"
# kills rekon run and every service at once (its session), as a power switch
# would, but with the page cache kept.
#
# The kill lands at the count, even at the last KF keyframe (which the mapper
# stores in its final pass, 0.3-0.6 s before it exits on the 90-frame room):
# each check reads the count with the service stopped (SIGSTOP), so the
# service runs only between checks (0.1 s apart) and the SIGKILL meets a live
# process holding what was counted. The service was once stopped only from one
# short on, and ran during the counts before that: under load a count took
# 1 s, the mapper went from 3 stored to 5 and exited during one, and nothing
# was killed (evidence /tmp/rekon_test_ORgdxx, 2026-12-04).
#
# Every check holds the player stopped (SIGSTOP) while it counts, so the
# stream advances only between checks, however slow a check is.
#
# Each check's time, count and outcome go to OUT/kill_checks.log (the
# evidence when a kill is missed).
#
# KILL_COUNT=fused: the count is of frames the mapper has fused (rows of
# OUT/mapper_timing.csv) instead of stored KF keyframes. KILL_COUNT=ended: 1
# once OUT/mapper.log says the end of the stream came, else 0.
#
# KILL_ALONE=1: once the count is reached the service is held stopped until
# every other service has exited (its peers take its silence for its end:
# set lifecycle.silence_s low), then killed: the last service standing.
#
# Prints "killed rekon-SERVICE ..." ("killed all ...") only when the kill
# landed (for a service: rekon run reported it killed by signal 9) and exits
# with rekon run's status; else prints "nothing killed: WHY" and exits 125.
# usage: kill_during_run.sh BIN_DIR SERVICE MIN_KEYFRAMES OUT [rekon run options...]
set -u
bin=$1 service=$2 min=$3 out=$4
shift 4
mkdir -p "$out"
setsid timeout 240 "$bin/rekon" run --out "$out" "$@" > "$out/run.out" 2>&1 &
run=$!  # the session of timeout, rekon run and its services

# KF keyframes in the run's store now (0 before it exists, once removed, or
# while a stopped writer holds its lock).
stored() {
  local segment
  segment=$(sed -n 's/^ *store_segment: *"\{0,1\}\([^"]*\)"\{0,1\} *$/\1/p' "$out/config.yaml" 2> /dev/null)
  [ -n "$segment" ] || { echo 0; return; }
  timeout 20 "$bin/rekon" keyframes --list --segment "$segment" 2> /dev/null |
    sed -n 's/^store [^ ]*: \([0-9]*\) keyframes.*/\1/p' | grep . || echo 0
}

# The pid of the newest instance of service $1, "" before it started.
pidOf() { sed -n "s/.*started rekon-$1 (pid \([0-9]*\)).*/\1/p" "$out/run.out" | tail -1; }

# Waits (1 s at most) until every thread of the process is stopped by
# SIGSTOP, hence alive and still: not running, not a zombie, not gone.
stopped() {
  local states
  for _ in $(seq 1 50); do
    states=$(sed 's/.*) //' /proc/"$1"/task/*/stat 2> /dev/null | cut -d' ' -f1 | sort -u)
    [ "$states" = T ] && return 0
    [ -n "$states" ] || return 1
    sleep 0.02
  done
  return 1
}

# One check: once the store holds MIN_KEYFRAMES, kills the service (or the
# session) and sets `killed`; returns 1 while it has not.
note() { echo "$(date +%T.%N | cut -c1-12) $*" >> "$out/kill_checks.log"; }
tryKill() {
  local n pid
  if [ "$service" = all ]; then
    n=$(stored)
    [ "$n" -ge "$min" ] || return 1
    # The session setsid made: rekon run and its services (each in a process group of its own).
    pkill -9 -s "$run" && killed="all (session $run) with $n KF keyframes stored"
    return 0
  fi
  pid=$(pidOf "$service")
  [ -n "$pid" ] && kill -STOP "$pid" 2> /dev/null && stopped "$pid" || { note "rekon-$service (pid ${pid:-none}) not stopped"; kill -CONT "$pid" 2> /dev/null; return 1; }
  if [ "${KILL_COUNT:-}" = fused ]; then
    n=$(( $(wc -l < "$out/mapper_timing.csv" 2> /dev/null || echo 1) - 1 ))
  elif [ "${KILL_COUNT:-}" = ended ]; then
    n=$(grep -c "end of stream after frame" "$out/mapper.log" 2> /dev/null)
  else
    n=$(stored)
  fi
  note "${KILL_COUNT:-stored} $n with rekon-$service (pid $pid) stopped"
  if [ "$n" -ge "$min" ]; then
    [ -n "${KILL_ALONE:-}" ] && waitAlone
    kill -9 "$pid" && killed="rekon-$service (pid $pid) with $n ${KILL_COUNT:-KF keyframes stored}"
    return 0
  fi
  kill -CONT "$pid" 2> /dev/null
  return 1
}

# The newest pids of the services other than SERVICE that are alive.
others() {
  local s p
  for s in player camera tracker optimiser mapper; do
    p=$(pidOf "$s")
    [ "$s" != "$service" ] && [ -n "$p" ] && kill -0 "$p" 2> /dev/null && echo "$p"
  done
}

# KILL_ALONE: the others run on (the player was held stopped for the check)
# until they have exited, 60 s at most.
waitAlone() {
  local p
  for p in $(others); do kill -CONT "$p" 2> /dev/null; done
  for _ in $(seq 1 600); do
    [ -z "$(others)" ] && { note "every other service has exited"; return; }
    sleep 0.1
  done
  note "other services still run after 60 s: $(others | tr '\n' ' ')"
}

# Why the fault was not injected, or "" when it was.
missed() {
  if [ -z "$killed" ]; then
    echo "the run ended before its store held $min KF keyframes with rekon-$service alive"
  elif [ "$service" != all ] && ! grep -q "rekon-$service was killed by signal 9" "$out/run.out"; then
    echo "SIGKILL was sent to $killed, but rekon run did not report it killed"
  fi
}

# Every check holds the player stopped, so the stream cannot run ahead of a
# check however slowly `rekon keyframes` starts on a loaded machine (it took
# longer than a whole 90-frame run under stress, and the kill was missed).
checkHoldingThePlayer() {
  local player rc
  player=$(pidOf player)
  [ -n "$player" ] && kill -STOP "$player" 2> /dev/null && stopped "$player"
  tryKill
  rc=$?
  [ -n "$player" ] && kill -CONT "$player" 2> /dev/null
  return $rc
}

killed=""
while kill -0 "$run" 2> /dev/null; do  # until the run ends (its timeout ends it)
  checkHoldingThePlayer && break
  sleep 0.1
done
wait "$run"
rc=$?
why=$(missed)
if [ -n "$why" ]; then
  echo "nothing killed: $why"
  exit 125
fi
echo "killed $killed"
exit $rc
