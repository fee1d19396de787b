"""The wire contract (shared/PROTOCOL.md, version 1): keys, MessagePack codecs, Zenoh options.

This is the one module that both the service and the clients import. It needs only
msgpack and the standard library (Zenoh is imported lazily by `open_session`), so a
display or a feed can be written against it without the estimation code.
"""

from __future__ import annotations

import argparse
import json
import re
import struct
from collections.abc import Sequence
from typing import Any

import msgpack
import numpy as np

PROTOCOL_VERSION = 1
DEFAULT_NS = "track"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
CHUNK = re.compile(r"^[A-Za-z0-9_-]+$")
STATUSES = ("tentative", "confirmed", "coasting")


# ---------------------------------------------------------------- keys
class Keys:
    """Key expressions of one namespace."""

    def __init__(self, ns: str = DEFAULT_NS) -> None:
        self.ns = ns.strip("/")

    def space(self, what: str) -> str:
        """Everything under `<ns>/<what>/`, e.g. space("meas") = `<ns>/meas/**`."""
        return f"{self.ns}/{what}/**"

    def meas(self, sensor: str = "*", target: str = "*") -> str:
        return f"{self.ns}/meas/{sensor}/{target}"

    def plots(self, sensor: str = "*") -> str:
        return f"{self.ns}/plots/{sensor}"

    def display(self, target: str = "*") -> str:
        return f"{self.ns}/display/{target}"

    def tracks(self, target: str = "*") -> str:
        return f"{self.ns}/tracks/{target}"

    def truth(self, target: str = "*") -> str:
        """Extension: ground truth published by simulation feeds for evaluation."""
        return f"{self.ns}/truth/{target}"

    def errors(self, sensor: str = "*") -> str:
        return f"{self.ns}/errors/{sensor}"

    def alive(self, instance: str = "*") -> str:
        return f"{self.ns}/alive/tracker/{instance}"

    @property
    def frame(self) -> str:
        return f"{self.ns}/frame"

    @property
    def clock(self) -> str:
        return f"{self.ns}/clock"

    @property
    def status(self) -> str:
        return f"{self.ns}/status"

    def chunks_after(self, key: str, what: str) -> list[str]:
        """The chunks of `key` after `<ns>/<what>/` (empty if the key is elsewhere)."""
        prefix = f"{self.ns}/{what}/"
        return key[len(prefix):].split("/") if key.startswith(prefix) else []


# ---------------------------------------------------------------- codecs
def pack(msg: dict[str, Any]) -> bytes:
    return msgpack.packb(msg, use_bin_type=True)


def unpack(data: bytes) -> Any:
    """Decode one MessagePack payload; raises ValueError on malformed bytes."""
    try:
        return msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several unrelated types
        raise ValueError(f"payload is not valid MessagePack: {exc}") from None


# display/<target> bodies for many tracks at once: the numbers of every body are written
# by NumPy into one buffer laid out as MessagePack (map of 8; float64 0xcb, big-endian;
# fixarray 0x93; fixstr 0xa0|len), and each body is its slice plus its packed strings.
_DISPLAY_HEAD = [(b"\x88\xa1t\xcb", "t"), (b"\xa3pos\x93\xcb", "p0"), (b"\xcb", "p1"),
                 (b"\xcb", "p2"), (b"\xa3vel\x93\xcb", "v0"), (b"\xcb", "v1"), (b"\xcb", "v2"),
                 (b"\xa5sigma\xcb", "sigma"), (b"\xa3age\xcb", "age")]


def _display_layout() -> tuple[np.dtype, bytes]:
    names, offsets, template = [], [], b""
    for prefix, name in _DISPLAY_HEAD:
        template += prefix + bytes(8)
        names.append(name)
        offsets.append(len(template) - 8)
    dtype = np.dtype({"names": names, "formats": [">f8"] * len(names), "offsets": offsets,
                      "itemsize": len(template)})
    return dtype, template


DISPLAY_DTYPE, DISPLAY_TEMPLATE = _display_layout()


def pack_displays(t: float, ids: Sequence[str], pos: np.ndarray, vel: np.ndarray,
                  sigma: np.ndarray, age: np.ndarray, status: Sequence[str],
                  shown: Sequence[str]) -> list[bytes]:
    """The `display/<id>` bodies of many tracks: the same maps as `pack` gives for
    {t, pos, vel, sigma, age, id, status, shown}, about five times faster."""
    n = len(ids)
    raw = np.frombuffer(DISPLAY_TEMPLATE * n, dtype=np.uint8).copy()
    rec = raw.view(DISPLAY_DTYPE)  # writes go through to raw, padding (markers) kept
    rec["t"] = t
    for k in range(3):
        rec[f"p{k}"], rec[f"v{k}"] = pos[:, k], vel[:, k]
    rec["sigma"], rec["age"] = sigma, age
    buf, size = raw.tobytes(), DISPLAY_DTYPE.itemsize
    strings = _strings_cache
    if len(strings) > 1 << 18:
        strings.clear()
    tails = [strings.get(k) or _strings(k) for k in zip(ids, status, shown, strict=True)]
    return [buf[i:i + size] + tail for i, tail in zip(range(0, n * size, size), tails, strict=True)]


_strings_cache: dict[tuple[str, str, str], bytes] = {}


def _strings(key: tuple[str, str, str]) -> bytes:
    out = _strings_cache[key] = b"".join(
        pack(k) + pack(v) for k, v in zip(("id", "status", "shown"), key, strict=True))
    return out


def f64_bin(values: Sequence[float]) -> bytes:
    """Little-endian float64 bytes of a flat sequence (numpy arrays: use .astype('<f8'))."""
    return struct.pack(f"<{len(values)}d", *values)


def f64_list(data: bytes) -> list[float]:
    return list(struct.unpack(f"<{len(data) // 8}d", data))


def decode_frame(msg: dict[str, Any]) -> list[dict[str, Any]]:
    """Split a `frame` message into per-track dicts {id, pos, vel, sigma}."""
    ids = msg["ids"]
    pos, vel, sig = (f64_list(msg[k]) for k in ("pos", "vel", "sigma"))
    return [
        {"id": i, "pos": pos[3 * n:3 * n + 3], "vel": vel[3 * n:3 * n + 3], "sigma": sig[n]}
        for n, i in enumerate(ids)
    ]


# ---------------------------------------------------------------- zenoh options
def add_zenoh_args(parser: argparse.ArgumentParser, ns: bool = True) -> None:
    """Zenoh options in the style of the zenoh-python examples."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--mode", choices=("peer", "client", "router"), help="session mode")
    g.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to (repeatable)")
    g.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)")
    g.add_argument("-c", "--config", metavar="FILE.json5", help="Zenoh configuration file")
    if ns:
        g.add_argument("--ns", default=DEFAULT_NS, help="key namespace (default %(default)s)")


def zenoh_config(args: argparse.Namespace, serve: bool = False) -> Any:
    """Build a zenoh.Config from parsed options.

    Multicast scouting is off unless the config file turns it on. With no endpoint
    given, a serving process (the tracker) listens on DEFAULT_ENDPOINT and a client
    process connects to it; anything else listens on loopback only.
    """
    import zenoh

    conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
    if not args.config:
        conf.insert_json5("scouting/multicast/enabled", "false")
    if args.mode:
        conf.insert_json5("mode", json.dumps(args.mode))
    connect, listen = list(args.connect), list(args.listen)
    if not args.config and not connect and not listen:
        (listen if serve else connect).append(DEFAULT_ENDPOINT)
    if not args.config and not listen and (args.mode or "peer") != "client":
        listen.append("tcp/127.0.0.1:0")
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    return conf


def peer_config(endpoint: str) -> Any:
    """A peer that connects to `endpoint` and listens on loopback only, multicast
    scouting off: the session of a tool or test talking to one known service."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    return conf


BLOCK_WAIT_US = 600_000_000  # 10 minutes


def patient(conf: Any) -> Any:
    """Let BLOCK puts wait for a slow receiver instead of closing its link after Zenoh's
    default 5 s of blocked transmission (which loses data): for lockstep services and
    for feeds, which must drop nothing (PROTOCOL.md)."""
    conf.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close",
                      str(BLOCK_WAIT_US))
    return conf


def open_session(args: argparse.Namespace, serve: bool = False) -> Any:
    import zenoh

    return zenoh.open(zenoh_config(args, serve))


def wait_for_tracker(session: Any, keys: Keys, count: int = 1, timeout: float = 30.0) -> bool:
    """Block until `count` tracker liveliness tokens are alive, or `timeout` s pass."""
    import threading

    import zenoh

    seen: set[str] = set()
    ready = threading.Event()

    def on_token(sample: Any) -> None:
        key = str(sample.key_expr)
        if sample.kind == zenoh.SampleKind.PUT:
            seen.add(key)
        else:
            seen.discard(key)
        if len(seen) >= count:
            ready.set()

    sub = session.liveliness().declare_subscriber(keys.alive("*"), on_token, history=True)
    try:
        return ready.wait(timeout)
    finally:
        sub.undeclare()
