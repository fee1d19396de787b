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


# ---------------------------------------------------------------- bulk maps
# The bodies of many tracks at once: the numbers of every row are written by NumPy into
# one buffer laid out as MessagePack (float 64 0xcb and int 64 0xd3, big-endian; fixarray
# 0x9n or array 16 0xdc), and each body is its row's slice followed by its own packed
# strings and maps. Decoded, the maps equal what `pack` gives for the same dicts.
def _layout(columns: Sequence[tuple[str, np.ndarray]], entries: int) -> tuple[np.dtype, bytes]:
    names, formats, offsets, template = [], [], [], pack_map_header(entries)
    for key, col in columns:
        width = col.shape[1] if col.ndim == 2 else 0
        template += pack(key)
        if col.ndim == 2:
            template += bytes([0x90 | width]) if width < 16 else b"\xdc" + width.to_bytes(2, "big")
        integer = col.dtype.kind in "iub"
        for k in range(max(width, 1)):
            template += (b"\xd3" if integer else b"\xcb") + bytes(8)
            names.append(f"{key}.{k}")
            formats.append(">i8" if integer else ">f8")
            offsets.append(len(template) - 8)
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                      "itemsize": len(template)})
    return dtype, template


def pack_map_header(entries: int) -> bytes:
    return bytes([0x80 | entries]) if entries < 16 else b"\xde" + entries.to_bytes(2, "big")


def pack_rows(columns: Sequence[tuple[str, np.ndarray]], tails: Sequence[bytes],
              tail_entries: int) -> list[bytes]:
    """One MessagePack map per row: the numeric `columns` ((N,) or (N, k) arrays, in this
    key order) then the row's `tails` (packed key-value pairs, `tail_entries` of them)."""
    n = len(tails)
    if not n:
        return []
    dtype, template = _layout(columns, len(columns) + tail_entries)
    raw = np.frombuffer(template * n, dtype=np.uint8).copy()
    rec = raw.view(dtype)  # writes go through to raw; the markers between stay
    for key, col in columns:
        for k in range(col.shape[1] if col.ndim == 2 else 1):
            rec[f"{key}.{k}"] = col[:, k] if col.ndim == 2 else col
    buf, size = raw.tobytes(), dtype.itemsize
    return [buf[i:i + size] + tail for i, tail in zip(range(0, n * size, size), tails, strict=True)]


class PackedStrings:
    """Packed key-value pairs of string fields, remembered (few distinct values)."""

    def __init__(self, keys: Sequence[str], limit: int = 1 << 18) -> None:
        self.keys, self.limit = tuple(keys), limit
        self.memo: dict[tuple, bytes] = {}

    def __call__(self, values: tuple) -> bytes:
        out = self.memo.get(values)
        if out is None:
            if len(self.memo) >= self.limit:
                self.memo.clear()
            out = self.memo[values] = b"".join(
                pack(k) + pack(v) for k, v in zip(self.keys, values, strict=True))
        return out


_DISPLAY_STRINGS = PackedStrings(("id", "status", "shown"))


def pack_displays(t: float, ids: Sequence[str], pos: np.ndarray, vel: np.ndarray,
                  sigma: np.ndarray, age: np.ndarray, status: Sequence[str],
                  shown: Sequence[str]) -> list[bytes]:
    """The `display/<id>` bodies of many tracks: {t, pos, vel, sigma, age, id, status,
    shown}."""
    tails = [_DISPLAY_STRINGS(k) for k in zip(ids, status, shown, strict=True)]
    return pack_rows([("t", np.full(len(ids), t)), ("pos", pos), ("vel", vel),
                      ("sigma", sigma), ("age", age)], tails, 3)


def pack_frame(t: float, ids: bytes, pos: np.ndarray, vel: np.ndarray,
               sigma: np.ndarray) -> bytes:
    """The `frame` body {t, ids, pos, vel, sigma} with `ids` already packed (it changes
    only when tracks come or go) and the arrays as little-endian float64 bytes."""
    return b"".join((pack_map_header(5), pack("t"), pack(float(t)), pack("ids"), ids,
                     pack("pos"), pack(pos.astype("<f8").tobytes()),
                     pack("vel"), pack(vel.astype("<f8").tobytes()),
                     pack("sigma"), pack(sigma.astype("<f8").tobytes())))


_TRACK_STRINGS = PackedStrings(("id", "model"))


def pack_tracks(t: np.ndarray, ids: Sequence[str], pos: np.ndarray, vel: np.ndarray,
                x: np.ndarray, p: np.ndarray, models: Sequence[Any], nis: np.ndarray,
                updates: np.ndarray) -> list[bytes]:
    """The `tracks/<id>` bodies of many tracks: {t, pos, vel, x, P (row-major), nis,
    updates, id, model}; a model is a name or a map (IMM mode probabilities)."""
    tails = [_TRACK_STRINGS((i, m)) if isinstance(m, str) else
             pack("id") + pack(i) + pack("model") + pack(m)
             for i, m in zip(ids, models, strict=True)]
    return pack_rows([("t", t), ("pos", pos), ("vel", vel), ("x", x), ("P", p), ("nis", nis),
                      ("updates", updates)], tails, 2)


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
