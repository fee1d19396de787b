"""Generated inputs, valid and invalid, each with the outcome the contract promises
(docs/protocol.md §4, §6.1): the strategies of tests/test_robustness.py and of
bench/bench_robustness.py.

Every payload goes to a key of its own (a fresh target or sensor chunk), so that each
rejection can be matched to its input by the `key` of its `errors/` message. A `Sent`
says what the service must do with it: apply `ok` measurements or detections (each
counted in `meas_accepted`; a labelled one publishes `tracks/<target>`), and reject
`bad` of them, each reported on `errors/` with the reason code `codes[i]` (None: any
documented code).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import msgpack
from hypothesis import assume
from hypothesis import strategies as st

from zenoh_track.wire import (
    BOUNDS,
    MAX_MEAS_BYTES,
    Keys,
    Rejected,
    f64_bin,
    pack,
    parse_measurement,
    parse_plots,
)

KEYS = Keys("track")
MAX_JUMP = 600.0  # the service's --max-jump (default)
NOISE = (10.0, math.radians(0.5), math.radians(0.5), 1.0)  # the service's defaults
_ids = itertools.count()


def fresh(prefix: str) -> str:
    return f"{prefix}{next(_ids)}"


@dataclass
class Sent:
    """One message and what the service must make of it."""

    key: str
    payload: bytes
    ok: int = 0  # measurements or detections applied
    codes: list[str | None] = field(default_factory=list)  # one per rejection
    target: str | None = None  # labelled and applied: tracks/<target> must follow
    targets: list[str] = field(default_factory=list)  # the same, for a batched scan

    @property
    def bad(self) -> int:
        return len(self.codes)


def finite(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


def number(lo: float, hi: float) -> st.SearchStrategy[float | int]:
    """A float, sometimes an integer, in [lo, hi]."""
    return st.one_of(finite(lo, hi), st.integers(math.ceil(lo), math.floor(hi)))


INT64 = st.integers(-2**63, 2**63 - 1)  # what MessagePack can carry
WRONG = st.one_of(st.text(max_size=4), st.booleans(), st.none(),
                  st.lists(st.text(max_size=2), min_size=1, max_size=3),
                  st.dictionaries(st.text(max_size=2), INT64, max_size=1))
NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf])


def _beyond(key: str) -> st.SearchStrategy[float | int]:
    """A value just or far outside the bounds of `key`."""
    lo, hi = BOUNDS[key]
    up = st.builds(lambda y: hi + max(abs(hi), 1.0) * y, finite(1e-6, 10.0))
    if lo == 0.0:
        return st.one_of(up, st.builds(lambda y: -y, finite(1e-9, 1e6)))
    return st.one_of(up, st.builds(lambda v: -v, up))


# ---------------------------------------------------------------- labelled measurements
@st.composite
def measurement(draw: Any, t: float) -> dict[str, Any]:
    """A valid labelled measurement of time in [t, t + 0.5)."""
    msg: dict[str, Any] = {"t": t + draw(finite(0.0, 0.49))}
    if draw(st.booleans()):
        msg |= {"r": draw(number(0.0, 1e6)), "az": draw(number(-math.pi, math.pi))}
        if draw(st.booleans()):
            msg["el"] = draw(number(-1.5, 1.5))
            if draw(st.booleans()):
                msg["sel"] = draw(number(0.0, 0.1))
        for k, hi in (("sr", 100.0), ("saz", 0.1)):
            if draw(st.booleans()):
                msg[k] = draw(number(0.0, hi))
    else:
        dim = draw(st.sampled_from([2, 3]))
        msg["pos"] = draw(st.lists(number(-1e6, 1e6), min_size=dim, max_size=dim))
        if draw(st.booleans()):
            msg["sigma"] = draw(st.one_of(number(0.0, 100.0), st.lists(
                number(0.0, 100.0), min_size=1, max_size=1), st.lists(
                number(0.0, 100.0), min_size=dim, max_size=dim)))
    if draw(st.booleans()):
        msg["sensor_pos"] = draw(st.lists(number(-1e5, 1e5), min_size=3, max_size=3))
    if draw(st.booleans()):
        msg["seq"] = draw(st.one_of(st.none(), st.integers(0, 2**53)))
    if draw(st.booleans()):  # unknown keys are ignored (the contract)
        msg["note"] = draw(st.text(max_size=8))
    return msg


def _read(msg: dict[str, Any]) -> list[str]:
    """The fields of a valid measurement that the service reads (a change to any other
    is ignored)."""
    if "pos" in msg:
        return ["t", "pos", "sigma", "sensor_pos", "seq"]
    return ["t", "r", "az", "sr", "saz", "sensor_pos", "seq"] + (
        ["el", "sel"] if "el" in msg else [])


@st.composite
def bad_measurement(draw: Any, t: float) -> tuple[bytes, str]:
    """(payload, reason code) of a measurement broken in one way."""
    msg = draw(measurement(t))
    how = draw(st.sampled_from(["type", "nan", "range", "time", "far", "drop_t", "both",
                                "int_key", "big", "truncated", "short_pos"]))
    key = draw(st.sampled_from(_read(msg)))
    vector = key in ("pos", "sensor_pos")
    if how == "type":
        wrong = draw(WRONG.filter(lambda v: key != "seq" or v is not None))
        if vector and draw(st.booleans()) and key in msg:
            msg[key] = [*msg[key][:-1], wrong if wrong is not None else "x"]
        else:
            msg[key] = wrong
        code = "bad_type"
    elif how == "nan" and key != "seq":
        bad = draw(NON_FINITE)
        if vector:
            msg[key] = [bad, *msg.get(key, [0.0, 0.0, 0.0])[1:]]
        elif key == "sigma" and isinstance(msg.get(key), list):
            msg[key] = [bad] * len(msg[key])
        else:
            msg[key] = bad
        code = "not_finite"
    elif how in ("range", "nan") and key == "seq":
        msg["seq"] = draw(st.one_of(st.integers(-2**40, -1), st.integers(2**53 + 1, 2**62)))
        code = "out_of_range"
    elif how == "range" and key != "t":
        bad = draw(_beyond(key))
        if vector:
            msg[key] = [bad, *msg.get(key, [0.0, 0.0, 0.0])[1:]]
        else:
            msg[key] = bad
        code = "out_of_range"
    elif how in ("range", "time"):
        msg["t"] = draw(st.sampled_from([1.0, -1.0])) * draw(finite(1.0000001e10, 1e300))
        code = "time_out_of_range"
    elif how == "far":
        sign = draw(st.sampled_from([1.0, -1.0]))
        msg["t"] = t + sign * (MAX_JUMP + draw(finite(2.0, 1e9)))
        code = "time_far"
    elif how == "drop_t":
        del msg["t"]
        code = "missing_field"
    elif how == "both":
        msg |= {"pos": [1.0, 2.0], "r": 5.0, "az": 0.0}
        code = "missing_field"
    elif how == "int_key":
        return msgpack.packb({**msg, draw(st.integers(0, 9)): 1}), "not_a_map"
    elif how == "big":
        msg["note"] = "x" * (MAX_MEAS_BYTES + draw(st.integers(0, 1000)))
        code = "too_large"
    elif how == "truncated":
        data = pack(msg)
        cut = draw(st.integers(0, len(data) - 1))
        return data[:cut], "not_a_map" if cut == 0 else "not_msgpack"
    else:  # short_pos
        msg.pop("r", None), msg.pop("az", None), msg.pop("el", None)
        msg["pos"] = draw(st.lists(number(-1.0, 1.0), min_size=0, max_size=1)) + \
            draw(st.sampled_from([[], [1.0, 2.0, 3.0]]))
        assume(len(msg["pos"]) not in (2, 3))
        code = "bad_type"
    return pack(msg), code


@st.composite
def labelled(draw: Any, t: float) -> list[Sent]:
    """One to three messages on a fresh measurement key, and what must become of them."""
    target, sensor = fresh("fz-"), draw(st.sampled_from(["fa", "fb"]))
    key = KEYS.meas(sensor, target)
    kind = draw(st.sampled_from(["valid", "bad", "bad", "garbage", "key", "duplicate",
                                 "late", "dimension"]))
    if kind == "valid":
        return [Sent(key, pack(draw(measurement(t))), ok=1, target=target)]
    if kind == "bad":
        payload, code = draw(bad_measurement(t))
        return [Sent(key, payload, codes=[code])]
    if kind == "garbage":
        payload = draw(st.binary(max_size=64))
        try:
            parse_measurement(sensor, target, payload, NOISE)
        except Rejected:
            return [Sent(key, payload, codes=[None])]
        assume(False)  # random bytes that happen to be a measurement: not this test's
    if kind == "key":
        bad_key = draw(st.sampled_from([KEYS.meas(target, "a") + "/b", f"track/meas/{target}"]))
        return [Sent(bad_key, pack(draw(measurement(t))), codes=["bad_key"])]
    first = draw(measurement(t))
    one = Sent(key, pack(first), ok=1, target=target)
    if kind == "duplicate":  # the same message again: the same sensor at the same time
        return [one, Sent(key, pack(first), codes=["duplicate"])]
    if kind == "late":  # older than the track's last update
        return [one, Sent(key, pack({**first, "t": first["t"] - 0.25}),
                          codes=["out_of_sequence"])]
    dim = len(first["pos"]) if "pos" in first else (3 if "el" in first else 2)
    other = {"t": first["t"] + 0.01, "pos": [1.0, 2.0] if dim == 3 else [1.0, 2.0, 3.0]}
    return [one, Sent(key, pack(other), codes=["dimension"])]


# ---------------------------------------------------------------- unlabelled scans
@st.composite
def detection(draw: Any) -> tuple[Any, str | None]:
    """(detection, None) for a valid one, (detection, code) for a bad one."""
    if draw(st.integers(0, 2)):
        if draw(st.booleans()):
            det = {"r": draw(number(0.0, 1e5)), "az": draw(number(-math.pi, math.pi))}
            if draw(st.booleans()):
                det["el"] = draw(number(-1.5, 1.5))
        else:
            det = {"pos": draw(st.lists(number(-1e5, 1e5), min_size=2, max_size=3))}
        return det, None
    how = draw(st.sampled_from(["r", "az", "el", "sr", "nan", "type", "map", "empty", "pos"]))
    base = {"r": 100.0, "az": 0.5, "el": 0.1}
    if how in ("r", "az", "el", "sr"):
        return {**base, how: draw(_beyond(how))}, "out_of_range"
    if how == "nan":
        return {**base, draw(st.sampled_from(["r", "az", "el"])): draw(NON_FINITE)}, \
            "not_finite"
    if how == "type":
        return {**base, draw(st.sampled_from(["r", "az", "el"])): draw(
            WRONG.filter(lambda v: v is not None))}, "bad_type"
    if how == "map":
        return draw(st.one_of(INT64, st.text(max_size=3), st.none())), "bad_type"
    if how == "empty":
        return {}, "missing_field"
    return {"pos": [draw(_beyond("pos")), 0.0]}, "out_of_range"


@st.composite
def scan(draw: Any, t: float) -> list[Sent]:
    """One `plots/` scan at time t from a fresh sensor: good and bad detections, columnar
    rows, or a scan broken as a whole."""
    sensor = fresh("fzp")
    key = KEYS.plots(sensor)
    form = draw(st.sampled_from(["dets", "dets", "columns", "broken", "garbage"]))
    if form == "dets":
        dets = draw(st.lists(detection(), max_size=8))
        head: dict[str, Any] = {"t": t}
        if draw(st.booleans()):
            head["sr"] = draw(number(0.0, 50.0))
        ok, codes = sum(c is None for _, c in dets), [c for _, c in dets if c]
        return [Sent(key, pack({**head, "dets": [d for d, _ in dets]}), ok=ok, codes=codes)]
    if form == "columns":
        n = draw(st.integers(0, 12))
        r = draw(st.lists(finite(0.0, 1e5), min_size=n, max_size=n))
        az = draw(st.lists(finite(-3.0, 3.0), min_size=n, max_size=n))
        bad = draw(st.lists(st.integers(0, max(n - 1, 0)), max_size=3, unique=True)) if n else []
        for i in bad:
            if draw(st.booleans()):
                r[i] = -draw(finite(1e-6, 1e6))
            else:
                az[i] = draw(st.sampled_from([math.nan, 7.0, -1e9]))
        codes = ["out_of_range" if r[i] < 0 or math.isfinite(az[i]) else "not_finite"
                 for i in sorted(bad)]
        return [Sent(key, pack({"t": t, "r": f64_bin(r), "az": f64_bin(az)}),
                     ok=n - len(bad), codes=codes)]
    if form == "garbage":
        payload = draw(st.binary(max_size=64))
        try:
            parse_plots(sensor, payload, NOISE)
        except Rejected:
            return [Sent(key, payload, codes=[None])]
        assume(False)
    how = draw(st.sampled_from(["no_t", "time", "far", "dets_type", "unequal", "odd_bin",
                                "both", "none"]))
    msg: dict[str, Any] = {"t": t, "dets": [{"r": 1.0, "az": 0.0}]}
    code = {"no_t": "missing_field", "time": "time_out_of_range", "far": "time_far",
            "dets_type": "bad_type", "unequal": "bad_type", "odd_bin": "bad_type",
            "both": "missing_field", "none": "missing_field"}[how]
    if how == "no_t":
        del msg["t"]
    elif how == "time":
        msg["t"] = 1e300
    elif how == "far":
        msg["t"] = t - MAX_JUMP - draw(finite(2.0, 1e6))
    elif how == "dets_type":
        msg["dets"] = draw(st.one_of(INT64, st.text(max_size=3)))
    elif how == "unequal":
        msg = {"t": t, "r": f64_bin([1.0, 2.0]), "az": f64_bin([0.0])}
    elif how == "odd_bin":
        msg = {"t": t, "r": f64_bin([1.0])[:7], "az": f64_bin([0.0])}
    elif how == "both":
        msg["r"] = f64_bin([1.0])
    else:
        del msg["dets"]
    return [Sent(key, pack(msg), codes=[code])]


# ---------------------------------------------------------------- batched labelled scans
@st.composite
def batched(draw: Any, t: float) -> list[Sent]:
    """One `scan/` message of fresh targets from a fresh sensor: polar rows, some bad
    (each refused alone, `row <i> (<id>): ...`), or a scan broken as a whole."""
    sensor = fresh("fzs")
    key = f"track/scan/{sensor}"
    n = draw(st.integers(0, 10))
    ids = [fresh("fzr-") for _ in range(n)]
    r = draw(st.lists(finite(0.0, 1e5), min_size=n, max_size=n))
    az = draw(st.lists(finite(-3.0, 3.0), min_size=n, max_size=n))
    bad = sorted(draw(st.lists(st.integers(0, n - 1), max_size=3, unique=True))) if n else []
    codes: list[str | None] = []
    for i in bad:
        how = draw(st.sampled_from(["r", "az_nan", "az_range"]))
        r[i], az[i] = ((-draw(finite(1e-6, 1e6)), az[i]) if how == "r" else
                       (r[i], math.nan) if how == "az_nan" else (r[i], 7.0))
        codes.append("not_finite" if how == "az_nan" else "out_of_range")
    msg: dict[str, Any] = {"t": t + draw(finite(0.0, 0.49)), "ids": ids, "r": f64_bin(r),
                           "az": f64_bin(az)}
    if n and draw(st.integers(0, 4)) == 0:  # broken as a whole
        how = draw(st.sampled_from(["ids", "unequal", "time"]))
        if how == "ids":
            msg["ids"] = draw(st.one_of(st.none(), st.text(max_size=3)))
        elif how == "unequal":
            msg["az"] = f64_bin([*az, 0.0])
        else:
            msg["t"] = 1e300
        code = {"ids": "missing_field", "unequal": "bad_type", "time": "time_out_of_range"}
        return [Sent(key, pack(msg), codes=[code[how]])]
    return [Sent(key, pack(msg), ok=n - len(bad), codes=codes,
                 targets=[x for i, x in enumerate(ids) if i not in bad])]


# ---------------------------------------------------------------- clock
@st.composite
def clock(draw: Any, t: float) -> list[Sent]:
    """A clock message: valid (applied, counted nowhere) or bad (rejected)."""
    how = draw(st.sampled_from(["valid", "nan", "time", "type", "missing"]))
    if how == "valid":
        return [Sent(KEYS.clock, pack({"t": t + draw(finite(0.0, 0.49))}))]
    value = {"nan": draw(NON_FINITE), "time": 1e300, "type": "soon"}.get(how)
    msg = {} if how == "missing" else {"t": value}
    code = {"nan": "not_finite", "time": "time_out_of_range", "type": "bad_type",
            "missing": "missing_field"}[how]
    return [Sent(KEYS.clock, pack(msg), codes=[code])]
