#!/usr/bin/env python3
"""Samples the memory of every rekon service started from BIN_DIR once a second
(/proc/PID/status: VmRSS split into anonymous, file and shared-memory pages)
and the keyframe store's usage every 10 s (`rekon keyframes --list`), until
killed. Usage: sample_memory.py BIN_DIR STORE_SEGMENT OUT_DIR"""
import os
import subprocess
import sys
import time

bin_dir, segment, out = os.path.realpath(sys.argv[1]), sys.argv[2], sys.argv[3]
mem = open(os.path.join(out, "memory.csv"), "w", buffering=1)
mem.write("unix_time,service,pid,rss_mb,anon_mb,file_mb,shmem_mb,hwm_mb\n")
store = open(os.path.join(out, "store.csv"), "w", buffering=1)
store.write("unix_time,keyframes,resident,shm_used_mib,shm_total_mib,spilled,spilled_mib\n")


def status(pid):
    fields = {}
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key in ("VmRSS", "RssAnon", "RssFile", "RssShmem", "VmHWM"):
                fields[key] = int(value.split()[0]) / 1024.0
    return fields


last_store = 0.0
while True:
    now = time.time()
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            exe = os.readlink(f"/proc/{pid}/exe")
            if os.path.dirname(exe) != bin_dir or not os.path.basename(exe).startswith("rekon-"):
                continue
            s = status(pid)
            mem.write(f"{now:.1f},{os.path.basename(exe)[6:]},{pid},{s['VmRSS']:.1f},{s['RssAnon']:.1f},"
                      f"{s['RssFile']:.1f},{s['RssShmem']:.1f},{s['VmHWM']:.1f}\n")
        except (OSError, KeyError):
            continue  # gone meanwhile, or not ours
    if now - last_store >= 10:
        last_store = now
        # rekon run may suffix the segment's name (one store per run): take the newest match.
        names = sorted((n for n in os.listdir("/dev/shm") if n == segment or n.startswith(segment + "_")),
                       key=lambda n: os.path.getmtime(os.path.join("/dev/shm", n)))
        first = ""
        if names:
            r = subprocess.run([os.path.join(bin_dir, "rekon"), "keyframes", "--list", "--segment", names[-1]],
                               capture_output=True, text=True)
            first = r.stdout.splitlines()[0] if r.returncode == 0 and r.stdout else ""
        # store NAME: K keyframes, R in shared memory (U of T MiB used), S spilled (M MiB in DIR)
        if first.startswith("store "):
            w = first.replace("(", " ").replace(")", " ").replace(",", " ").split()
            store.write(f"{now:.1f},{w[2]},{w[4]},{w[8]},{w[10]},{w[13]},{w[15]}\n")
    time.sleep(max(0.0, 1.0 - (time.time() - now)))
