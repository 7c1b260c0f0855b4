#!/usr/bin/env bash
# Runs `rekon run` and kills one of its services with SIGKILL mid-run: once
# the mapper's keyframe store holds MIN_KEYFRAMES KF keyframes. Prints
# "killed rekon-SERVICE" when it did; exits with rekon run's status. SERVICE
# "all" kills rekon run and every service at once (its session), as a power
# switch would, but with the page cache kept: prints "killed all".
# usage: kill_during_run.sh BIN_DIR SERVICE MIN_KEYFRAMES OUT [rekon run options...]
set -u
bin=$1 service=$2 min=$3 out=$4
shift 4
mkdir -p "$out"
setsid timeout 240 "$bin/rekon" run --out "$out" "$@" > "$out/run.out" 2>&1 &
run=$!  # the session of timeout, rekon run and its services
for _ in $(seq 1 1200); do  # 120 s at most
  kill -0 "$run" 2> /dev/null || break
  segment=$(sed -n 's/^ *store_segment: *"\{0,1\}\([^"]*\)"\{0,1\} *$/\1/p' "$out/config.yaml" 2> /dev/null)
  if [ -n "$segment" ]; then
    n=$(timeout 10 "$bin/rekon" keyframes --list --segment "$segment" 2> /dev/null | sed -n 's/^store [^ ]*: \([0-9]*\) keyframes.*/\1/p')
    if [ "${n:-0}" -ge "$min" ]; then
      if [ "$service" = all ]; then
        # The session setsid made: rekon run and its services (each in a process group of its own).
        pkill -9 -s "$run" && echo "killed all (session $run) with $n KF keyframes stored"
        break
      fi
      pid=$(sed -n "s/.*started rekon-$service (pid \([0-9]*\)).*/\1/p" "$out/run.out" | tail -1)
      kill -9 "$pid" && echo "killed rekon-$service (pid $pid) with $n KF keyframes stored"
      break
    fi
  fi
  sleep 0.1
done
wait "$run"
