#!/usr/bin/env bash
# Runs a command in a private network namespace whose loopback carries LCM
# multicast (lo up, multicast on, 224.0.0.0/4 routed to lo), so multi-process
# tests never send traffic anywhere else and never meet another test's bus.
set -euo pipefail
exec unshare -n bash -c 'ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo && exec "$@"' in_netns "$@"
