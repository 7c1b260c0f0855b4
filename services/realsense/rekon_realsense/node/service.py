"""What every rekon service process shares (common/src/service.cpp, in
Python): the command line (--config, --set, --out, --help), logging in the
C++ services' shape ("[HH:MM:SS.mmm] [name] [level] text"), the bus with a
thread that dispatches messages, a heartbeat (every lifecycle.heartbeat_s and
at once on a state change; the last one says "exited"), live numbers on STATS
once a second, stopping on SIGINT/SIGTERM or a shutdown message, and
<out>/<name>_stats.json (with peak_rss_mb) at exit, published on STATS too."""
import argparse
import json
import logging
import os
import resource
import signal
import socket
import sys
import threading
import time

from rekon_msgs import done_t, heartbeat_t, service_stats_t, shutdown_t

from .bus import Bus
from ..config import Config
from ..errors import Error

log = logging.getLogger("rekon")

HEARTBEAT, STATS, SHUTDOWN, DONE = "HEARTBEAT", "STATS", "SHUTDOWN", "DONE"


def now_micros():
    return int(time.time() * 1e6)


def peak_rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class _Formatter(logging.Formatter):
    def __init__(self, name):
        super().__init__()
        self.name = name

    def format(self, record):
        t = time.localtime(record.created)
        level = {"WARNING": "warning", "CRITICAL": "critical"}.get(record.levelname, record.levelname.lower())
        return (f"[{time.strftime('%H:%M:%S', t)}.{int(record.msecs):03d}] [{self.name}] [{level}] "
                f"{record.getMessage()}")


def setup_logging(name, level):
    levels = {"trace": logging.DEBUG, "debug": logging.DEBUG, "info": logging.INFO, "warn": logging.WARNING,
              "warning": logging.WARNING, "error": logging.ERROR}
    if level not in levels:
        raise Error(f"log level '{level}' is unknown; use trace, debug, info, warn or error")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Formatter(name))
    log.handlers[:] = [handler]
    log.setLevel(levels[level])
    log.propagate = False


class Lifecycle:
    """lifecycle.* (LifecycleTimes::fromConfig): every wait scaled by load_factor."""

    def __init__(self, config):
        load = config.get_double("lifecycle.load_factor")
        if not load >= 1.0:
            raise Error("lifecycle.load_factor must be 1 or more (it only ever lengthens the timeouts)")
        self.heartbeat_s = config.get_double("lifecycle.heartbeat_s")
        if not self.heartbeat_s > 0:
            raise Error("lifecycle.heartbeat_s must be a positive number of seconds")
        self.silence_s = config.get_double("lifecycle.silence_s") * load
        self.silence_gaps = config.get_double("lifecycle.silence_gaps")
        if not self.silence_gaps >= 2:
            raise Error("lifecycle.silence_gaps must be 2 or more")


class ServiceContext:
    def __init__(self, name, config, out_dir, args):
        self.name = name
        self.config = config
        self.out_dir = out_dir
        self.args = args
        drop = config.get_double("lcm.drop_fraction")
        if drop < 0 or drop >= 1:
            raise Error("lcm.drop_fraction must be in [0, 1)")
        self.bus = Bus(config.get_string("lcm.url"), config.get_string("lcm.channel_prefix"))
        self.lifecycle = Lifecycle(config)
        self.stats = {}
        self.last_frame = -1
        self._stop = threading.Event()
        self._threads_stop = threading.Event()
        self._state = "starting"
        self._state_changed = threading.Condition()
        self._live = {}
        self._live_changed = False
        self._live_lock = threading.Lock()
        self._threads = []
        self._exited_sent = False
        self.bus.subscribe(SHUTDOWN, shutdown_t, self._on_shutdown)

    def _on_shutdown(self, msg):
        log.info("shutdown requested (%s)", msg.reason)
        self.request_stop()

    def stop_requested(self):
        return self._stop.is_set()

    def sleep(self, seconds):
        """Waits `seconds`, or less when a stop is requested meanwhile (then True)."""
        return self._stop.wait(seconds)

    def request_stop(self):
        self._stop.set()

    def set_state(self, state):
        with self._state_changed:
            if self._state == state:
                return
            self._state = state
            self._state_changed.notify_all()

    def set_live(self, key, value):
        with self._live_lock:
            self._live_changed |= self._live.get(key) != value
            self._live[key] = value

    def start(self):
        for target in (self._bus_loop, self._heartbeat_loop):
            t = threading.Thread(target=target, daemon=True)
            t.start()
            self._threads.append(t)

    def _bus_loop(self):
        try:
            while not self._threads_stop.is_set():
                self.bus.handle(100)
        except Exception as e:  # a handler's exception: one line, and the service stops cleanly
            log.error("%s", e)
            self.request_stop()

    def heartbeat(self):
        hb = heartbeat_t()
        hb.service = self.name
        hb.pid = os.getpid()
        hb.host = socket.gethostname()
        hb.utime = now_micros()
        hb.last_frame_id = self.last_frame
        hb.state = self._state
        return hb

    def _publish_live(self):
        with self._live_lock:
            if not self._live_changed:
                return
            self._live_changed = False
            body = dict(self._live)
        self.bus.publish(STATS, self._stats_message(body))

    def _stats_message(self, body):
        m = service_stats_t()
        m.service = self.name
        m.utime = now_micros()
        m.json = json.dumps(body)
        return m

    def _heartbeat_loop(self):
        try:
            last_live = time.monotonic()
            while not self._threads_stop.is_set():
                if time.monotonic() - last_live >= 1.0:
                    last_live = time.monotonic()
                    self._publish_live()
                with self._state_changed:
                    hb = self.heartbeat()
                self.bus.publish(HEARTBEAT, hb)
                with self._state_changed:
                    self._state_changed.wait_for(
                        lambda: self._threads_stop.is_set() or self._state != hb.state, self.lifecycle.heartbeat_s)
        except Exception as e:  # peers will see this instance fall silent; the service stops with its outputs
            log.error("heartbeat thread: %s", e)
            self.request_stop()

    def stop_threads(self):
        with self._state_changed:
            self._threads_stop.set()
            self._state_changed.notify_all()
        for t in self._threads:
            t.join()
        self._threads = []
        if self._exited_sent:
            return
        self._exited_sent = True
        with self._state_changed:
            self._state = "exited"
        try:
            self.bus.publish(HEARTBEAT, self.heartbeat())
        except Exception as e:
            log.warning("the exit heartbeat was not published: %s", e)

    def write_stats(self):
        self.stats["peak_rss_mb"] = peak_rss_mb()
        if self.bus.malformed:
            self.stats["malformed_messages"] = self.bus.malformed
        try:
            self.bus.publish(STATS, self._stats_message(self.stats))
        except Exception as e:  # the file below matters more than the watchers
            log.warning("stats not published on the bus: %s", e)
        if self.out_dir:
            path = os.path.join(self.out_dir, f"{self.name}_stats.json")
            with open(path, "w", encoding="utf-8") as f:
                json.dump(self.stats, f, indent=2)
                f.write("\n")


class PeerWatch:
    """What this service knows of its peers from heartbeats and done_t, per
    instance (pid), as PeerWatch in common/src/service.cpp: a new pid is the
    current instance; a peer is finished when never seen, done and exited, or
    silent for lifecycle.silence_s (and silence_gaps x its longest gap)."""

    def __init__(self, bus, lifecycle):
        self._lifecycle = lifecycle
        self._lock = threading.Lock()
        self._peers = {}  # service -> dict(pid, done, exited, last, gap)
        self._superseded = {}
        bus.subscribe(HEARTBEAT, heartbeat_t, self._on_heartbeat)
        bus.subscribe(DONE, done_t, self._on_done)

    def _current(self, service, pid):
        p = self._peers.get(service)
        if p is not None and p["pid"] == pid:
            return p
        if pid in self._superseded.setdefault(service, set()):
            return None
        if p is not None:
            self._superseded[service].add(p["pid"])
        p = {"pid": pid, "done": False, "exited": False, "last": None, "gap": 0.0}
        self._peers[service] = p
        return p

    def _on_heartbeat(self, hb):
        with self._lock:
            p = self._current(hb.service, hb.pid)
            if p is None:
                return
            now = time.monotonic()
            if p["last"] is not None:
                p["gap"] = max(p["gap"], now - p["last"])
            p["last"] = now
            p["exited"] = hb.state == "exited"

    def _on_done(self, m):
        with self._lock:
            p = self._current(m.service, m.pid)
            if p is not None:
                p["done"] = True

    def _silent(self, p):
        return p["last"] is not None and time.monotonic() - p["last"] > max(
            self._lifecycle.silence_s, p["gap"] * self._lifecycle.silence_gaps)

    def finished(self, names):
        with self._lock:
            for n in names:
                p = self._peers.get(n)
                if p is None:
                    continue
                if p["last"] is None:
                    if not p["done"]:
                        return False
                    continue
                if not ((p["done"] and p["exited"]) or self._silent(p)):
                    return False
            return True

    def wait_until_finished(self, names, ctx):
        while not ctx.stop_requested() and not self.finished(names):
            time.sleep(0.05)


def _on_signal(ctx):
    def handler(_signum, _frame):
        ctx.request_stop()
    return handler


def run_service(argv, name, summary, add_options, body, epilog=None):
    """Parses the common options and those add_options adds, sets everything
    up, runs body(ctx) and writes the stats. Returns the exit code: 0, or 1
    after logging any error as one line (stats written all the same)."""
    parser = argparse.ArgumentParser(prog=f"rekon-{name}", description=summary, epilog=epilog,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="", help="YAML config laid over config/default.yaml")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override one config key, e.g. --set log.level=debug")
    parser.add_argument("--out", default="", help="folder for this service's outputs and stats (created if missing)")
    add_options(parser)
    args = parser.parse_args(argv)
    try:
        config = Config.load(args.config, args.set)
        setup_logging(name, config.get_string("log.level"))
        if args.out:
            try:
                os.makedirs(args.out, exist_ok=True)
            except OSError as e:
                raise Error(f"cannot create the output folder {args.out} ({e.strerror}); check the path") from None
        ctx = ServiceContext(name, config, args.out, args)
    except Error as e:  # before the service runs: nothing measured yet
        if log.handlers:
            log.error("%s", e)
        else:
            print(f"rekon-{name}: error: {e}", file=sys.stderr)
        return 1
    signal.signal(signal.SIGINT, _on_signal(ctx))
    signal.signal(signal.SIGTERM, _on_signal(ctx))
    try:
        ctx.start()
        body(ctx)
        ctx.set_state("finished")
        ctx.stop_threads()
        ctx.write_stats()
        return 0
    except Exception as e:  # rekon's Error and the SDK's RuntimeError alike: one line
        log.error("%s", e if isinstance(e, Error) else f"{type(e).__name__}: {e}")
        ctx.stop_threads()
        try:
            ctx.write_stats()  # whatever was measured before the error is kept
        except Exception as e2:
            log.error("%s", e2)
        return 1
