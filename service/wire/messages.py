"""Validation of input messages against the contract: bytes in, checked records out.

Every rejection raises `Rejected` with a reason a feed's author can act on; nothing
here touches a track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .codec import Rejected, decode_map, unpack
from .keys import (
    BOUNDS,
    CHUNK,
    MAX_ANGLE_NOISE,
    MAX_AZ,
    MAX_DISTANCE,
    MAX_EL,
    MAX_MEAS_BYTES,
    MAX_SEQ,
    MAX_TIME,
)


@dataclass(frozen=True, slots=True)
class Measurement:
    """One labelled measurement, checked. Polar: values = (r, az[, el]); Cartesian: pos."""

    sensor: str
    target: str
    t: float
    dim: int  # 2 or 3: dimension of the track it feeds
    polar: bool
    values: tuple[float, ...]
    sigmas: tuple[float, ...]  # polar: (sr, saz[, sel]); Cartesian: one per axis
    sensor_pos: tuple[float, float, float]
    seq: int | None
    sigma_t: float | None = None  # s: the std of the time t (None: not stated)


_ANY = (-math.inf, math.inf)


def _num(msg: dict[str, Any], key: str) -> float:
    """The field `key` of msg as a float: a number, finite, within `keys.BOUNDS[key]`."""
    v = msg[key]
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise Rejected(f"field '{key}' must be a number, got {type(v).__name__}")
    try:
        v = float(v)
    except OverflowError:  # an integer beyond float64
        v = math.copysign(math.inf, v)
    if not math.isfinite(v):
        raise Rejected(f"field '{key}' is not finite ({v})")
    lo, hi = BOUNDS.get(key, _ANY)
    if not lo <= v <= hi:
        if key == "t":
            raise Rejected(f"time t={v!r} is outside the plausible range |t| <= {hi:g} s")
        raise Rejected(f"field '{key}' must be >= {lo}, got {v}" if v < lo else
                       f"field '{key}' must be <= {hi}, got {v}")
    return v


def _vec(msg: dict[str, Any], key: str, sizes: tuple[int, ...]) -> tuple[float, ...]:
    v = msg[key]
    if not isinstance(v, list | tuple) or len(v) not in sizes:
        raise Rejected(f"field '{key}' must be a list of {' or '.join(map(str, sizes))} numbers")
    return tuple(_num({key: x}, key) for x in v)


POLAR_3D = frozenset(("t", "r", "az", "el", "sr", "saz", "sel", "seq"))


def parse_measurement(
    sensor: str, target: str, payload: bytes, defaults: tuple[float, float, float, float]
) -> Measurement:
    """Check one `<ns>/meas/<sensor>/<target>` payload.

    `defaults` = (sr, saz, sel, sigma): the noise used when a message gives none.
    """
    msg = _fast_polar(sensor, target, payload)
    if msg is not None:  # the common case, all checks passed at once
        return Measurement(sensor, target, msg[0], 3, True, msg[1:4], msg[4:7],
                           (0.0, 0.0, 0.0), msg[7])
    return parse_full(sensor, target, payload, defaults)


def parse_full(
    sensor: str, target: str, payload: bytes, defaults: tuple[float, float, float, float]
) -> Measurement:
    """`parse_measurement` field by field, naming the first problem found."""
    for what, chunk in (("sensor", sensor), ("target", target)):
        if not CHUNK.fullmatch(chunk):
            raise Rejected(f"{what} chunk '{chunk[:64]}' must be letters, digits, '-' or '_'")
    msg = decode_map(payload, MAX_MEAS_BYTES)
    if "t" not in msg:
        raise Rejected("missing required field 't'")
    t = _num(msg, "t")
    polar, cart = "r" in msg or "az" in msg, "pos" in msg
    if polar == cart:
        raise Rejected("exactly one of polar (r, az[, el]) or 'pos' must be present")
    sensor_pos = _vec(msg, "sensor_pos", (3,)) if "sensor_pos" in msg else (0.0, 0.0, 0.0)
    seq = msg.get("seq")
    if seq is not None and (isinstance(seq, bool) or not isinstance(seq, int)):
        raise Rejected("field 'seq' must be an integer")
    if seq is not None and not 0 <= seq <= MAX_SEQ:
        raise Rejected(f"field 'seq' must be in [0, 2^53], got {seq}")
    sigma_t = _num(msg, "sigma_t") if "sigma_t" in msg else None
    if polar:
        if "r" not in msg or "az" not in msg:
            raise Rejected("polar measurement needs both 'r' and 'az'")
        values = (_num(msg, "r"), _num(msg, "az"))
        sig = [msg.get("sr", defaults[0]), msg.get("saz", defaults[1])]
        names = ["sr", "saz"]
        if "el" in msg:
            values += (_num(msg, "el"),)
            sig.append(msg.get("sel", defaults[2]))
            names.append("sel")
        sigmas = tuple(_num({n: s}, n) for n, s in zip(names, sig, strict=True))
        return Measurement(sensor, target, t, len(values), True, values, sigmas, sensor_pos, seq,
                           sigma_t)
    pos = _vec(msg, "pos", (2, 3))
    raw = msg.get("sigma", defaults[3])
    if isinstance(raw, list | tuple):
        if len(raw) not in (1, len(pos)):
            raise Rejected(f"field 'sigma' must have 1 or {len(pos)} entries")
        sig = tuple(_num({"sigma": s}, "sigma") for s in raw)
    else:
        sig = (_num({"sigma": raw}, "sigma"),)
    sigmas = sig * len(pos) if len(sig) == 1 else sig
    return Measurement(sensor, target, t, len(pos), False, pos, sigmas, sensor_pos, seq,
                       sigma_t)


def _fast_polar(sensor: str, target: str, payload: bytes) -> tuple | None:
    """(t, r, az, el, sr, saz, sel, seq) of a well-formed 3-D polar measurement with all
    its fields given as floats, within bounds; None for anything else (the full check
    then runs and names the problem)."""
    if len(payload) > MAX_MEAS_BYTES:
        return None
    try:
        msg = unpack(payload)
        if type(msg) is not dict or not POLAR_3D.issuperset(msg) or len(msg) < 7:
            return None
        v = (t, r, az, el, sr, saz, sel) = (msg["t"], msg["r"], msg["az"], msg["el"],
                                            msg["sr"], msg["saz"], msg["sel"])
        seq = msg.get("seq")
        f = float
        if not (type(t) is f and type(r) is f and type(az) is f and type(el) is f
                and type(sr) is f and type(saz) is f and type(sel) is f
                and math.isfinite(math.fsum(v))):
            return None
    except (ValueError, KeyError, OverflowError):  # fsum overflows on huge finite values
        return None
    if (not (0.0 <= r <= MAX_DISTANCE and -MAX_AZ <= az <= MAX_AZ and -MAX_EL <= el <= MAX_EL
             and -MAX_TIME <= t <= MAX_TIME and 0.0 <= sr <= MAX_DISTANCE
             and 0.0 <= saz <= MAX_ANGLE_NOISE and 0.0 <= sel <= MAX_ANGLE_NOISE)
            or (seq is not None and (type(seq) is not int or not 0 <= seq <= MAX_SEQ))
            or not (CHUNK.fullmatch(sensor) and CHUNK.fullmatch(target))):
        return None
    return (*v, seq)


def parse_clock(payload: bytes) -> float:
    """The `t` of one `<ns>/clock` payload, checked like a measurement's."""
    msg = decode_map(payload, MAX_MEAS_BYTES)
    if "t" not in msg:
        raise Rejected("clock message needs field 't'")
    return _num(msg, "t")
