"""The rekon bus from Python: LCM (the `lcm` package, the same wire protocol
as the C++ services' liblcm) with the types lcm-gen -p generates from
messages/*.lcm at build time. As common/src/bus.cpp: channel names carry the
configured prefix, every message carries schema_version, and a message that
does not decode or speaks another schema version is dropped with one logged
line (the service goes on)."""
import logging
import threading

import lcm

from rekon_schema import SCHEMA_VERSION

from ..errors import Error

log = logging.getLogger("rekon")


# Inline frames are 0.5-1.5 MB; as common/src/bus.cpp, ask for a 4 MiB receive
# buffer unless the URL says otherwise (the kernel caps it at net.core.rmem_max).
RECV_BUF_OPTION = "recv_buf_size=4194304"


def with_receive_buffer(url):
    if not url.startswith("udpm://") or "recv_buf_size" in url:
        return url
    return url + ("&" if "?" in url else "?") + RECV_BUF_OPTION


class Bus:
    def __init__(self, url, prefix):
        try:
            self._lcm = lcm.LCM(with_receive_buffer(url))
        except Exception as e:  # lcm raises a bare RuntimeError/IOError for a bad URL or no network
            raise Error(f"cannot open the LCM bus at {url} ({e}); check lcm.url and that multicast is routed "
                        "(README: 'route add -net 224.0.0.0 netmask 240.0.0.0 dev lo')") from None
        self.prefix = prefix
        self.malformed = 0
        self._publish_lock = threading.Lock()

    def channel(self, name):
        return self.prefix + name

    def publish(self, name, msg):
        msg.schema_version = SCHEMA_VERSION
        data = msg.encode()
        with self._publish_lock:
            self._lcm.publish(self.channel(name), data)

    def subscribe(self, name, msg_type, handler):
        channel = self.channel(name)

        def on_message(_channel, data):
            try:
                msg = msg_type.decode(data)
            except Exception:  # a wrong fingerprint or a truncated buffer: dropped, counted, logged
                self._malformed(channel, f"does not decode as {msg_type.__name__} (wrong fingerprint or truncated)")
                return
            if msg.schema_version != SCHEMA_VERSION:
                self._malformed(channel, f"schema_version {msg.schema_version} but this build speaks "
                                         f"{SCHEMA_VERSION}; run the same rekon version everywhere")
                return
            handler(msg)

        self._lcm.subscribe(channel, on_message)

    def _malformed(self, channel, why):
        self.malformed += 1
        if self.malformed <= 10 or self.malformed % 1000 == 0:
            log.error("dropped a malformed message on %s: %s (%d malformed so far)", channel, why, self.malformed)

    def handle(self, timeout_ms):
        return self._lcm.handle_timeout(timeout_ms) > 0
