#!/usr/bin/env bash
# run_hosts.sh one|two BIN_DIR DATASET OUT [--set KEY=VALUE ...]
# Runs rekon-player, rekon-tracker, rekon-optimiser and rekon-mapper as
# separate processes, the way an operator starts them on real machines:
#   one: all four on one "host" (a private network + UTS namespace);
#   two: player and tracker on host rekon-host-a, optimiser and mapper on
#        rekon-host-b, each its own network and UTS namespace (own hostname),
#        joined by a veth pair with 224.0.0.0/4 routed over it.
# Both hosts live inside one outer `unshare -n`, so neither can reach a real
# interface; the namespaces die with their processes (nothing named to clean
# up). Every service runs under a timeout; its log is OUT/<service>.log.
set -euo pipefail
mode="$1" bin="$2" dataset="$3" out="$4"
shift 4
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
limit="${REKON_HOSTS_TIMEOUT_S:-240}"
mkdir -p "$out"
# ttl=1: multicast must cross the veth (ttl=0 never leaves the host).
common=(--out "$out" --set "lcm.url=udpm://239.255.76.67:7667?ttl=1&recv_buf_size=4194304" --set "transport.segment=rekon_hosts_$$" "$@")

# start NAME ARGS...: a service in the background under the timeout.
start() {
  local name="$1"
  shift
  timeout -k 5 "$limit" "$bin/rekon-$name" "${common[@]}" "$@" >"$out/$name.log" 2>&1 &
  echo $! >"$out/$name.pid"
}
# finish NAME...: waits for each, fails naming the first that did not exit 0.
finish() {
  local rc=0 status
  for name in "$@"; do
    status=0
    wait "$(cat "$out/$name.pid")" || status=$?
    if [ "$status" -ne 0 ]; then
      echo "rekon-$name on $(hostname) exited with status $status; last lines of $out/$name.log:" >&2
      tail -5 "$out/$name.log" >&2
      rc=1
    fi
  done
  return $rc
}

case "$mode" in
  one)
    [ -n "${REKON_HOSTS_INSIDE:-}" ] || exec env REKON_HOSTS_INSIDE=1 unshare -n -u "$0" one "$bin" "$dataset" "$out" "$@"
    hostname rekon-host-a
    ip link set lo up
    ip link set lo multicast on
    ip route add 224.0.0.0/4 dev lo
    start tracker; start optimiser; start mapper
    start player --dataset "$dataset"
    finish player tracker optimiser mapper
    ;;
  two)
    [ -n "${REKON_HOSTS_INSIDE:-}" ] || exec env REKON_HOSTS_INSIDE=a unshare -n -u "$0" two "$bin" "$dataset" "$out" "$@"
    case "$REKON_HOSTS_INSIDE" in
      a)
        hostname rekon-host-a
        ip link set lo up
        # Host B: a namespace of its own, started first so its end of the veth can move in.
        rm -f "$out/host-b.ready"
        REKON_HOSTS_INSIDE=b unshare -n -u "$0" two "$bin" "$dataset" "$out" "$@" &
        host_b=$!
        for _ in $(seq 100); do [ -e "$out/host-b.ready" ] && break; sleep 0.05; done
        [ -e "$out/host-b.ready" ] || { echo "host B did not start" >&2; exit 1; }
        ip link add rekon-a type veth peer name rekon-b netns "$host_b"
        ip addr add 10.213.0.1/30 dev rekon-a
        ip link set rekon-a multicast on up
        ip route add 224.0.0.0/4 dev rekon-a
        touch "$out/host-a.ready"
        start tracker
        start player --dataset "$dataset"
        rc=0
        finish player tracker || rc=1
        wait "$host_b" || { echo "host B (optimiser, mapper) failed" >&2; rc=1; }
        exit $rc
        ;;
      b)
        hostname rekon-host-b
        ip link set lo up
        touch "$out/host-b.ready"
        for _ in $(seq 100); do [ -e "$out/host-a.ready" ] && break; sleep 0.05; done
        ip link show rekon-b >/dev/null 2>&1 || { echo "the veth never reached host B" >&2; exit 1; }
        ip addr add 10.213.0.2/30 dev rekon-b
        ip link set rekon-b multicast on up
        ip route add 224.0.0.0/4 dev rekon-b
        start optimiser; start mapper
        finish optimiser mapper
        ;;
    esac
    ;;
  *)
    echo "usage: run_hosts.sh one|two BIN_DIR DATASET OUT [--set KEY=VALUE ...]" >&2
    exit 2
    ;;
esac
