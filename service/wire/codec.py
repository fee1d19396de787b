"""MessagePack codecs of the contract: every message is one MessagePack map."""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence
from typing import Any

import msgpack

from .keys import STATUSES

# the Zenoh encoding of every MessagePack payload (docs/protocol.md, "Encodings"): zenoh has
# no predefined id for it, so it travels as this MIME string
MSGPACK_ENCODING = "application/msgpack"


class Rejected(ValueError):
    """An input that breaks the contract; the message is the reason a feed's author reads,
    `code` its kind (a key of `status`'s `rejected_by_reason`)."""

    @property
    def code(self) -> str:
        return reason_code(str(self))


# The kind of every rejection the service gives, by the words its reason starts with or
# contains (checked in order; the first match wins): a short, stable set of codes, so
# that counting by code stays bounded whatever the inputs (docs/protocol.md §4).
REASON_CODES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("internal", ("internal error",)),
    ("too_large", ("payload of ", "more than the limit")),
    ("not_msgpack", ("payload is not valid MessagePack",)),
    ("not_a_map", ("payload must be a MessagePack map", "map keys must be strings")),
    ("bad_key", ("key must be <ns>/", "chunk '")),
    ("time_out_of_range", ("outside the plausible range", "or out of bounds")),
    ("time_far", ("from the picture's time",)),
    ("not_finite", ("is not finite",)),
    ("out_of_range", ("must be >= ", "must be <= ", "must be in [")),
    ("bad_type", ("must be a number", "must be a list", "must be an integer",
                  "must be a bin", "must be a map", "must have 1 or", "must be 2 or 3",
                  "not a multiple of 8", "not rows of", "is not ", "unequal lengths",
                  "bytes, not", "rows, 'ids'")),
    ("missing_field", ("missing required field", "needs", "exactly one of", "either",
                       "send one form")),
    ("duplicate", ("duplicate",)),
    ("out_of_sequence", ("out of sequence", "late scan")),
    ("dimension", ("-D measurement for a",)),
    ("non_finite_result", ("gave a non-finite",)),
)


_ROW = re.compile(r"^(?:detection \d+|row \d+ \([^)]*\)): ")


def reason_code(reason: str) -> str:
    """The code of a rejection reason (a scan's `detection <i>: ` or `row <i> (<id>): `
    prefix ignored); `other` for a reason no entry of REASON_CODES names."""
    reason = _ROW.sub("", reason, count=1)
    for code, words in REASON_CODES:
        if any(w in reason for w in words):
            return code
    return "other"


def pack(msg: dict[str, Any]) -> bytes:
    return msgpack.packb(msg, use_bin_type=True)


def unpack(data: bytes) -> Any:
    """Decode one MessagePack payload; raises ValueError on malformed bytes."""
    try:
        return msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several unrelated types
        raise ValueError(f"payload is not valid MessagePack: {exc}") from None


def check_size(payload: bytes, limit: int) -> None:
    """`Rejected` when a payload is longer than `limit` bytes (keys.MAX_*_BYTES)."""
    if len(payload) > limit:
        raise Rejected(f"payload of {len(payload)} bytes is longer than the limit of "
                       f"{limit} bytes")


def decode_map(payload: bytes, limit: int | None = None) -> dict[str, Any]:
    """The map of one payload; `Rejected` for anything else (longer than `limit` bytes,
    empty, malformed, not a map, a key that is not a string)."""
    if limit is not None:
        check_size(payload, limit)
    try:
        msg = unpack(payload) if payload else None
    except ValueError as exc:
        raise Rejected(str(exc)) from None
    if not isinstance(msg, dict):
        raise Rejected("payload must be a MessagePack map")
    for k in msg:
        if type(k) is not str:
            raise Rejected(f"map keys must be strings, got {type(k).__name__}")
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
