"""realsense.* and transport.* of the config (config/default.yaml), read and
checked once, each bad value one line naming its key."""
from .errors import Error


class Params:
    """realsense.* and transport.* (config/default.yaml), checked once."""

    def __init__(self, config):
        g = config
        self.device = g.get_string("realsense.device")
        self.playback = g.get_string("realsense.playback")
        self.calibration = g.get_string("realsense.calibration")
        self.width = g.get_int("realsense.width")
        self.height = g.get_int("realsense.height")
        self.fps = g.get_int("realsense.fps")
        # YAML 1.1 (PyYAML) reads an unquoted on/off as true/false.
        self.emitter = {"true": "on", "false": "off"}.get(g.get_string("realsense.emitter"),
                                                          g.get_string("realsense.emitter"))
        self.preset = g.get_string("realsense.preset")
        self.depth_units = g.get_double("realsense.depth_units")
        self.encoding = g.get_string("realsense.encoding")
        self.record = g.get_string("realsense.record")
        self.record_queue = g.get_int("realsense.record_queue")
        self.wait_for = g.get_string_list("realsense.wait_for")
        self.wait_timeout_s = g.get_double("realsense.wait_timeout_s")
        self.max_frames = g.get_int("realsense.max_frames")
        self.reconnect_timeout_s = g.get_double("realsense.reconnect_timeout_s")
        self.reconnect_wait_s = g.get_double("realsense.reconnect_wait_s")
        self.restarted = g.get_bool("realsense.restarted")
        self.transport_mode = g.get_string("transport.mode")
        self.segment = g.get_string("transport.segment")
        self.slots = g.get_int("transport.slots")
        self.max_width = g.get_int("transport.max_width")
        self.max_height = g.get_int("transport.max_height")
        self.in_flight = g.get_int("transport.live_in_flight")
        from .device import PRESETS
        from .images import ENCODINGS
        if self.emitter not in ("auto", "on", "off"):
            raise Error(f"realsense.emitter '{self.emitter}' is unknown; use on, off or auto (the device's setting)")
        if self.preset and self.preset not in PRESETS:
            raise Error(f"realsense.preset '{self.preset}' is unknown; use one of {', '.join(PRESETS)} or \"\" "
                        "(the device's)")
        if not (self.depth_units == 0 or 1e-6 <= self.depth_units <= 0.01):
            raise Error(f"realsense.depth_units {self.depth_units:g} is out of range; give metres per depth unit "
                        "(0.001 = 1 mm, 0.0001 = 0.1 mm) or 0 for the device's")
        if self.encoding not in ENCODINGS:
            raise Error(f"realsense.encoding '{self.encoding}' is unknown; use netpbm (this host) or png (a network)")
        if min(self.width, self.height, self.fps) <= 0:
            raise Error("realsense.width, realsense.height and realsense.fps must be positive")
        if self.in_flight < 1:
            raise Error("transport.live_in_flight must be 1 or more")
        if self.record_queue < 1:
            raise Error("realsense.record_queue must be 1 or more (frames)")
        if not self.reconnect_wait_s > 0:
            raise Error("realsense.reconnect_wait_s must be a positive number of seconds")
        if self.reconnect_timeout_s < 0:
            raise Error("realsense.reconnect_timeout_s must be 0 (never reopen) or more seconds")
        if self.transport_mode not in ("auto", "lcm", "shm"):
            raise Error(f"transport mode '{self.transport_mode}' is unknown; use shm, lcm or auto")
