"""MessagePack codecs of the contract: every message is one MessagePack map."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

import msgpack

from .keys import STATUSES


class Rejected(ValueError):
    """An input that breaks the contract; the message is the reason a feed's author reads."""


def pack(msg: dict[str, Any]) -> bytes:
    return msgpack.packb(msg, use_bin_type=True)


def unpack(data: bytes) -> Any:
    """Decode one MessagePack payload; raises ValueError on malformed bytes."""
    try:
        return msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several unrelated types
        raise ValueError(f"payload is not valid MessagePack: {exc}") from None


def decode_map(payload: bytes) -> dict[str, Any]:
    """The map of one payload; `Rejected` for anything else (empty, malformed, not a map)."""
    try:
        msg = unpack(payload) if payload else None
    except ValueError as exc:
        raise Rejected(str(exc)) from None
    if not isinstance(msg, dict):
        raise Rejected("payload must be a MessagePack map")
    return msg


def f64_bin(values: Sequence[float]) -> bytes:
    """Little-endian float64 bytes of a flat sequence (numpy arrays: use .astype('<f8'))."""
    return struct.pack(f"<{len(values)}d", *values)


def f64_list(data: bytes) -> list[float]:
    return list(struct.unpack(f"<{len(data) // 8}d", data))


def decode_frame(msg: dict[str, Any]) -> list[dict[str, Any]]:
    """Split a `frame` message into per-track dicts {id, pos, vel, sigma}, with `status`
    (a name of STATUSES) when the frame carries its status bin (protocol 1.1)."""
    ids = msg["ids"]
    pos, vel, sig = (f64_list(msg[k]) for k in ("pos", "vel", "sigma"))
    rows = [
        {"id": i, "pos": pos[3 * n:3 * n + 3], "vel": vel[3 * n:3 * n + 3], "sigma": sig[n]}
        for n, i in enumerate(ids)
    ]
    codes = msg.get("status")
    if isinstance(codes, bytes) and len(codes) == len(rows):
        for row, code in zip(rows, codes, strict=True):
            row["status"] = STATUSES[code] if code < len(STATUSES) else "unknown"
    return rows
