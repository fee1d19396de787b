"""Checks of `<ns>/plots/<sensor>` scans (docs/protocol.md §3.2): bytes in, one `PlotScan` out.

A scan is one map `{t, sensor_pos?, sr?, saz?, sel?, sigma?, ...}` whose detections come
either as `dets`, a list of maps `{r, az, el?} | {pos}`, or in columnar form: bins of
little-endian float64 `r`, `az`[, `el`] or `pos` (rows of `dim` = 2 or 3 numbers), one row a
detection. Every detection is checked exactly as a labelled measurement carrying the scan's
`t`, `sensor_pos` and noise fields plus its own fields (`parse_full` is the reference; the
plain cases are built without it, with the same result). A bad detection is set aside with
its reason, the others are kept; a scan that cannot be read as a whole raises `Rejected`.

Project extensions: a `dets` entry may carry its own `sr`, `saz`, `sel`, `sigma`, which
override the scan's; `sigma` may be a list per axis in both forms; `dim` (2 or 3) gives the
width of a columnar `pos` (without it, the row count of another bin must tell it).
"""

from __future__ import annotations

import math
import struct
from collections import deque
from dataclasses import dataclass, fields, replace
from itertools import compress, repeat
from typing import Any

from .codec import Rejected, decode_map, pack
from .keys import BOUNDS, MAX_ROWS, MAX_SCAN_BYTES
from .messages import Measurement, _num, _vec, parse_full

MAX_DETECTIONS = MAX_ROWS  # per scan; documented limit, larger scans are rejected whole

NOISE = ("sr", "saz", "sel", "sigma")
COLUMNS = ("r", "az", "el", "pos")  # the detection fields of the columnar form
DET_FIELDS = (*COLUMNS, *NOISE)  # what a detection reads of a `dets` entry; the rest is ignored
_TARGET = "plot"  # parse_full wants a valid target chunk; the records get target ""


@dataclass(frozen=True, slots=True)
class PlotScan:
    """One checked scan: its good detections in order, and why the others were set aside."""

    sensor: str
    t: float
    sensor_pos: tuple[float, float, float]
    detections: tuple[Measurement, ...]  # the good ones, in order; target == "" (unlabelled)
    index: tuple[int, ...]  # each good detection's index in the message
    rejected: tuple[tuple[int, str], ...]  # (index, reason) of each bad detection


def parse_plots(
    sensor: str, payload: bytes, noise: tuple[float, float, float, float]
) -> PlotScan:
    """Check one `<ns>/plots/<sensor>` payload.

    `noise` = (sr, saz, sel, sigma): the noise used when neither the scan nor a detection
    gives one. Raises `Rejected` when the scan as a whole is unreadable; a bad detection is
    listed in `rejected` as `(i, "detection <i>: <reason>")`, the reason worded as
    `parse_full` words it for a labelled measurement.
    """
    msg = decode_map(payload, MAX_SCAN_BYTES)
    # the sensor chunk, `t` and `sensor_pos` checked as a labelled message's, by parse_full
    # itself (with a placeholder detection)
    head = {k: msg[k] for k in ("t", "sensor_pos") if k in msg}
    ref = parse_full(sensor, _TARGET, pack({**head, "pos": [0.0, 0.0], "sigma": 0.0}), noise)
    t, sensor_pos = ref.t, ref.sensor_pos
    columnar = [k for k in COLUMNS if k in msg]
    if "dets" in msg and columnar:
        raise Rejected(f"scan has both 'dets' and columnar fields ({', '.join(columnar)}); "
                       "send one form")
    if "dets" not in msg and not columnar:
        raise Rejected("scan needs 'dets' (a list of detections) or columnar bins "
                       "('r' and 'az' [and 'el'], or 'pos')")
    scan = _Scan(sensor, t, sensor_pos, msg, head, noise)
    out, checked = scan.dets() if "dets" in msg else scan.columns()
    rejected = tuple((i, f"detection {i}: {out[i]}") for i in sorted(checked)
                     if type(out[i]) is str)
    keep = [True] * len(out)
    for i, _ in rejected:
        keep[i] = False
    return PlotScan(sensor, t, sensor_pos, tuple(compress(out, keep)),
                    tuple(compress(range(len(out)), keep)), rejected)


class _Scan:
    """The scan-wide part of one scan, and the detections checked against it: each becomes
    its `Measurement` or the text of its rejection."""

    def __init__(self, sensor: str, t: float, sensor_pos: tuple[float, ...], msg: dict[str, Any],
                 head: dict[str, Any], noise: tuple[float, float, float, float]) -> None:
        self.sensor, self.t, self.sensor_pos, self.msg, self.noise = (
            sensor, t, sensor_pos, msg, noise)
        self.base = dict(head)  # the scan's fields in every detection's map (plus its noise)
        # noise in effect where a detection gives none (floats; bins are read per row)
        self.eff: dict[str, Any] = dict(zip(NOISE, noise, strict=True))

    def scan_noise(self, key: str) -> None:
        """Check a scan-wide noise field: a number >= 0 (for `sigma` also a list per axis)."""
        v = self.msg[key]
        per_axis = key == "sigma" and isinstance(v, list | tuple)
        values = [_num({key: x}, key)
                  for x in (_vec(self.msg, key, (1, 2, 3)) if per_axis else (v,))]
        self.eff[key] = values if per_axis else values[0]
        self.base[key] = v

    def full(self, row: dict[str, Any]) -> Measurement | str:
        """The reference check: parse_full on the detection's fields merged over the scan's."""
        try:
            m = parse_full(self.sensor, _TARGET, pack({**self.base, **row}), self.noise)
        except Rejected as exc:
            return str(exc)
        return replace(m, target="")

    # ------------------------------------------------------------ `dets`: a list of maps
    def dets(self) -> tuple[list[Measurement | str], list[int]]:
        """Each entry's record or reason, and the indices of those the full check saw."""
        dets = self.msg["dets"]
        if not isinstance(dets, list):
            raise Rejected(f"field 'dets' must be a list of detections, got {type(dets).__name__}")
        _limit(len(dets))
        for key in NOISE:
            if key in self.msg:
                self.scan_noise(key)
        out: list[Any] = [None] * len(dets)
        good, vals, sigs, polar, slow = [], [], [], [], []
        for i, det in enumerate(dets):
            if type(det) is dict and (p := self.plain(det)) is not None:
                good.append(i)
                vals.append(p[0])
                sigs.append(p[1])
                polar.append("pos" not in det)
                continue
            slow.append(i)
            out[i] = (self.full({k: det[k] for k in DET_FIELDS if k in det})
                      if type(det) is dict else
                      f"must be a map {{r, az[, el]}} or {{pos}}, got {type(det).__name__}")
        records = _records(len(good), sensor=self.sensor, target="", t=self.t,
                           dim=[len(v) for v in vals], polar=polar, values=vals, sigmas=sigs,
                           sensor_pos=self.sensor_pos, seq=None, sigma_t=None)
        for i, m in zip(good, records, strict=True):
            out[i] = m
        return out, slow

    def plain(self, det: dict[str, Any]) -> tuple[tuple, tuple] | None:
        """(values, sigmas) of a detection made of floats, finite and in bounds, read without
        the full check; None for anything else (`full` then builds it or names its problem)."""
        eff, get = self.eff, det.get
        if "pos" in det:
            pos, s = det["pos"], get("sigma", eff["sigma"])
            if "r" in det or "az" in det or type(pos) is not list or not 2 <= len(pos) <= 3:
                return None
            vals = tuple(pos)
            sig = _axes(s, len(pos)) if type(s) is list else (s,) * len(pos)
            if sig is None:
                return None
            names = _CART[len(pos)]
        elif "r" in det and "az" in det:
            if "el" in det:
                vals = (det["r"], det["az"], det["el"])
                sig = (get("sr", eff["sr"]), get("saz", eff["saz"]), get("sel", eff["sel"]))
                names = _POLAR3
            else:
                vals = (det["r"], det["az"])
                sig = (get("sr", eff["sr"]), get("saz", eff["saz"]))
                names = _POLAR2
        else:
            return None
        every = vals + sig
        if {*map(type, every)} != _FLOAT or not math.isfinite(sum(every)):
            return None  # a finite sum of floats proves each finite (overflow: full check)
        for v, (lo, hi) in zip(every, names, strict=True):
            if not lo <= v <= hi:
                return None
        return vals, sig

    # ------------------------------------------------------------ columnar: bins
    def columns(self) -> tuple[list[Measurement | str], set[int]]:
        """Each row's record or reason, and the indices of those the full check saw."""
        polar, width, n, cols = self.bins()
        if polar:
            names = ("r", "az", "el") if "el" in cols else ("r", "az")
            vals = list(zip(*(cols[k] for k in names), strict=True))
            noise = [cols[k] if k in cols else [self.eff[k]] * n for k in NOISE[:len(names)]]
            sigs = list(zip(*noise, strict=True))
        else:
            vals = list(zip(*[iter(cols["pos"])] * width, strict=True))
            if "sigma" in cols:
                sigs = [(x,) * width for x in cols["sigma"]]
            else:
                s = self.eff["sigma"]
                one = _axes(s, width) if type(s) is list else (s,) * width
                sigs = [one] * n  # one is None: no row is good, the full check says why
        bad = self.bad(polar, width, n, cols)
        out: list[Measurement | str] = _records(
            n, sensor=self.sensor, target="", t=self.t, dim=len(names) if polar else width,
            polar=polar, values=vals, sigmas=sigs, sensor_pos=self.sensor_pos, seq=None,
            sigma_t=None)
        for i in bad:
            out[i] = self.row(i, polar, cols)
        return out, bad

    def row(self, i: int, polar: bool, cols: dict[str, list[float]]) -> Measurement | str:
        """The full check of row i of a columnar scan (`bins`): its record or reason."""
        row = {k: c[i] for k, c in cols.items() if k != "pos"}
        return self.full(row if polar else {**row, "pos": self._pos(i, cols)})

    def bad(self, polar: bool, width: int, n: int, cols: dict[str, list[float]]) -> set[int]:
        """The rows of a columnar scan (`bins`) that need the full check: a value not
        finite or out of bounds, a column at a time (`bad_rows`)."""
        if polar:
            names = ("r", "az", "el") if "el" in cols else ("r", "az")
            keys = NOISE[:len(names)]
            if any(bad_rows([self.eff[k]], k) for k in keys if k not in cols):
                return set(range(n))  # a scan-wide (or the default) noise is bad
            return bad_rows(cols["r"], "r").union(
                *(bad_rows(cols[k], k) for k in names[1:]),
                *(bad_rows(cols[k], k) for k in keys if k in cols))
        if "sigma" in cols:
            bad = bad_rows(cols["sigma"], "sigma")
        else:
            s = self.eff["sigma"]
            one = _axes(s, width) if type(s) is list else (s,) * width
            bad = set(range(n)) if one is None or bad_rows(list(one), "sigma") else set()
        return bad | {j // width for j in bad_rows(cols["pos"], "pos")}

    def bins(self) -> tuple[bool, int, int, dict[str, list[float]]]:
        """The columnar form read: polar or not, the width of a `pos` row, the row count and
        each bin as a list of floats (scan-wide noise fields checked into `eff`). Raises
        `Rejected` when the bins cannot be read as one table."""
        msg = self.msg
        polar = "pos" not in msg
        if not polar and any(k in msg for k in ("r", "az", "el")):
            raise Rejected("columnar scan carries either 'r', 'az' [, 'el'] or 'pos', not both")
        if polar and not ("r" in msg and "az" in msg):
            raise Rejected("columnar polar scan needs both 'r' and 'az'")
        bins: dict[str, bytes] = {}
        for key in (k for k in (*COLUMNS, *NOISE) if k in msg):
            v = msg[key]
            if isinstance(v, bytes):
                if len(v) % 8:
                    raise Rejected(f"bin '{key}' has {len(v)} bytes, not a multiple of 8 "
                                   "(float64)")
                bins[key] = v
            elif key in NOISE:
                self.scan_noise(key)
            else:
                raise Rejected(f"field '{key}' must be a bin of little-endian float64, "
                               f"got {type(v).__name__}")
        rows = {k: len(v) // 8 for k, v in bins.items()}
        width = 1 if polar else self.width(rows)
        if not polar:
            if rows["pos"] % width:
                raise Rejected(f"bin 'pos' has {len(bins['pos'])} bytes, not rows of {width} "
                               "float64")
            rows["pos"] //= width
        if len(set(rows.values())) > 1:
            raise Rejected("columnar bins have unequal lengths ("
                           + ", ".join(f"{k} {n} rows" for k, n in rows.items()) + ")")
        n = rows["r" if polar else "pos"]
        _limit(n)
        cols = {k: list(struct.unpack(f"<{len(v) // 8}d", v)) for k, v in bins.items()}
        self._width = width
        return polar, width, n, cols

    def _pos(self, i: int, cols: dict[str, list[float]]) -> list[float]:
        w = self._width
        return cols["pos"][i * w:(i + 1) * w]

    def width(self, rows: dict[str, int]) -> int:
        """The number of values in a row of `pos`: `dim` if given, else the row count of the
        scan's other bins tells it."""
        if "dim" in self.msg:
            dim = self.msg["dim"]
            if type(dim) is not int or dim not in (2, 3):
                raise Rejected(f"field 'dim' (the width of 'pos') must be 2 or 3, got {dim!r}")
            return dim
        if not rows["pos"]:
            return 3  # no detection: the width does not matter
        others = {n for k, n in rows.items() if k != "pos"}
        if not others:
            raise Rejected("columnar 'pos' needs 'dim' (2 or 3), the width of its rows cannot "
                           "be told from its length")
        n = max(others)  # several: the lengths are unequal, reported after
        if n == 0 or rows["pos"] % n or rows["pos"] // n not in (2, 3):
            raise Rejected(f"bin 'pos' of {rows['pos']} float64 is not {n} rows of 2 or 3 "
                           f"(the row count of the other bins); give 'dim'")
        return rows["pos"] // n


def _limit(n: int) -> None:
    if n > MAX_DETECTIONS:
        raise Rejected(f"scan has {n} detections, more than the limit of {MAX_DETECTIONS}")


def _axes(s: Any, dim: int) -> tuple | None:
    """Per-axis Cartesian sigmas of a plain list of 1 or dim floats; None otherwise."""
    if type(s) is not list or len(s) not in (1, dim):
        return None
    return tuple(s) * dim if len(s) == 1 else tuple(s)


def bad_rows(col: list[float], key: str) -> set[int]:
    """Indices of the values (floats) of column `key` that are not finite or outside
    `keys.BOUNDS[key]`: the checks of a field, a whole column at once (the sum, min and
    max run in C; only a column with a bad value is looked at row by row). Reusable by
    every columnar input."""
    lo, hi = BOUNDS.get(key, (-math.inf, math.inf))
    if not col or math.isfinite(sum(col)) and min(col) >= lo and max(col) <= hi:
        return set()
    return {i for i, v in enumerate(col) if not (math.isfinite(v) and lo <= v <= hi)}


_FLOAT = {float}
_B = BOUNDS
_POLAR2 = (_B["r"], _B["az"], _B["sr"], _B["saz"])
_POLAR3 = (_B["r"], _B["az"], _B["el"], _B["sr"], _B["saz"], _B["sel"])
_CART = {n: (_B["pos"],) * n + (_B["sigma"],) * n for n in (2, 3)}
_NEW = object.__new__
_SET = {f.name: Measurement.__dict__[f.name].__set__ for f in fields(Measurement)}


def _records(n: int, **columns: Any) -> list[Measurement]:
    """n Measurements built column by column, the loops in C (about 2.5 times faster than
    calling the constructor per record; Measurement has no __post_init__). A column is a
    list of n values or one value for all."""
    assert columns.keys() == _SET.keys()
    out = list(map(_NEW, repeat(Measurement, n)))
    for name, col in columns.items():
        deque(map(_SET[name], out, col if isinstance(col, list) else repeat(col)), 0)
    return out
