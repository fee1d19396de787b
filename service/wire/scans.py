"""Checks of `<ns>/scan/<sensor>` (contract 1.1): many labelled measurements in one
columnar message, bytes in, checked records out (docs/protocol.md §3.4).

`{t, ids: [str...], r, az[, el] | pos, sr?, saz?, sel?, sigma?, sigma_t?, sensor_pos?, dim?}`:
`t` a float (all rows) or a bin of N little-endian float64, `r`, `az`, `el` bins of N
float64, `pos` a bin of (N, 2) or (N, 3) float64, each noise field (and `sigma_t`, the std
of the time, contract 1.x: docs/protocol.md, "Time noise") a float or a bin of N float64.
Row i means exactly what `meas/<sensor>/<ids[i]>` with those values would mean: the
values are checked a column at a time (`plots.bad_rows`), and a row with a bad value goes
through the reference check `parse_full` for its reason. A bad row is rejected alone; a
scan that cannot be read as a whole (unequal lengths, unreadable bins, no `ids`) raises
`Rejected`.
"""

from __future__ import annotations

import re
import struct
from collections import deque
from dataclasses import dataclass, replace

from .codec import Rejected, decode_map, pack
from .keys import CHUNK, MAX_SCAN_BYTES
from .messages import Measurement, _num, parse_full
from .plots import _SET, NOISE, _axes, _limit, _Scan, bad_rows


@dataclass(frozen=True, slots=True)
class LabelledScan:
    """One checked batched scan: its good rows in order, and why the others were set aside."""

    sensor: str
    measurements: list[Measurement]  # the good rows, in order
    rejected: list[tuple[int, str]]  # (row, "row <i> (<id>): <reason>") of each bad row


def _front(sensor: str, payload: bytes, noise: tuple[float, float, float, float]
           ) -> tuple[list[str], list[float] | None, set[int], _Scan, _TimeNoise]:
    """The scan-wide checks: the ids, each row's time (None: one for all), the rows whose
    time is bad, the scan's columnar detections ready to be checked and its time noise."""
    msg = decode_map(payload, MAX_SCAN_BYTES)
    ids = msg.get("ids")
    if not isinstance(ids, list) or set(map(type, ids)) - {str}:
        raise Rejected("batched scan needs 'ids', a list of target ids (strings)")
    n = len(ids)
    _limit(n)
    if "t" not in msg:
        raise Rejected("missing required field 't'")
    t = msg["t"]
    times: list[float] | None = None
    bad_t: set[int] = set()
    if isinstance(t, bytes):
        if len(t) != 8 * n:
            raise Rejected(f"bin 't' has {len(t)} bytes, not {n} float64 (one per id)")
        times = list(struct.unpack(f"<{n}d", t))
        bad_t = bad_rows(times, "t")
        head_t = next((v for i, v in enumerate(times) if i not in bad_t), 0.0)
        msg = {**msg, "t": head_t}  # the scan-wide checks see one good time
    if "pos" in msg and "dim" not in msg and isinstance(msg["pos"], bytes) and n:
        msg = {**msg, "dim": len(msg["pos"]) // 8 // n}  # the ids give the row count
    for k in ("r", "pos"):
        if isinstance(msg.get(k), bytes) and not len(msg[k]) % 8:
            rows = len(msg[k]) // 8 // (1 if k == "r" else max(1, msg.get("dim", 1)))
            if rows != n:
                raise Rejected(f"bin '{k}' has {rows} rows, 'ids' {n}")
    # the values: checked exactly as an unlabelled scan's columnar detections
    head = {k: msg[k] for k in ("t", "sensor_pos") if k in msg}
    ref = parse_full(sensor, "scan", pack({**head, "pos": [0.0, 0.0], "sigma": 0.0}), noise)
    if "r" not in msg and "pos" not in msg:
        raise Rejected("batched scan needs bins 'r' and 'az' [and 'el'], or 'pos'")
    return (ids, times, bad_t, _Scan(sensor, ref.t, ref.sensor_pos, msg, head, noise),
            _time_noise(msg, n))


_TimeNoise = tuple[list[float] | float | None, set[int]]  # sigma_t (rows or all), bad rows


def _time_noise(msg: dict, n: int) -> _TimeNoise:
    """The scan's `sigma_t`: absent (None), one number for all rows (a bad one rejects
    the scan) or a bin of n float64 (a bad value rejects its row)."""
    if "sigma_t" not in msg:
        return None, set()
    v = msg["sigma_t"]
    if not isinstance(v, bytes):
        return _num(msg, "sigma_t"), set()
    if len(v) != 8 * n:
        raise Rejected(f"bin 'sigma_t' has {len(v)} bytes, not {n} float64 (one per id)")
    col = list(struct.unpack(f"<{n}d", v))
    return col, bad_rows(col, "sigma_t")


def _reason(i: int, target: str, m: Measurement | str | None, times: list[float] | None,
            bad_t: set[int], time_noise: _TimeNoise = (None, set())) -> str | None:
    """Why row i is rejected (None: it is good), in the order of the checks: its values,
    its id, its time, its time noise."""
    if type(m) is str:
        reason = m
    elif not CHUNK.fullmatch(target):
        reason = f"target chunk '{target}' must be letters, digits, '-' or '_'"
    elif i in bad_t:
        reason = f"field 't' is not finite or out of bounds ({times[i]})"  # type: ignore[index]
    elif i in time_noise[1]:
        reason = (f"field 'sigma_t' is not finite or out of bounds "
                  f"({time_noise[0][i]})")  # type: ignore[index]
    else:
        return None
    return f"row {i} ({target[:64]}): {reason}"


def parse_scan(sensor: str, payload: bytes,
               noise: tuple[float, float, float, float]) -> LabelledScan:
    """Check one `<ns>/scan/<sensor>` payload (`noise`: the service's default noise): a
    record per good row (the reference of `parse_scan_columns`)."""
    ids, times, bad_t, scan, time_noise = _front(sensor, payload, noise)
    out, _ = scan.columns()
    good: list[int] = []
    rejected: list[tuple[int, str]] = []
    for i, (target, m) in enumerate(zip(ids, out, strict=True)):
        reason = _reason(i, target, m, times, bad_t, time_noise)
        if reason is None:
            good.append(i)
        else:
            rejected.append((i, reason))
    records = [out[i] for i in good]
    deque(map(_SET["target"], records, [ids[i] for i in good]), 0)
    if times is not None:
        deque(map(_SET["t"], records, [times[i] for i in good]), 0)
    st = time_noise[0]
    if st is not None:
        deque(map(_SET["sigma_t"], records,
                  [st[i] for i in good] if isinstance(st, list) else [st] * len(good)), 0)
    return LabelledScan(sensor, records, rejected)  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class ScanColumns:
    """One checked batched scan as columns, without a record per row (the service's fast
    path): row i of the message is good when i is in `good`; its values are the i-th of
    each column, or, for a row in `fixed`, that record's (a row the full check accepted
    although a column check flagged it)."""

    sensor: str
    n: int  # rows in the message
    good: list[int]  # the good rows, in order
    ids: list[str]  # their target ids
    t: list[float] | float  # every row's time, or one for all
    dim: int
    polar: bool
    values: list[list[float]]  # per axis, every row: (r, az[, el]) or (x, y[, z])
    sigmas: list[list[float] | float]  # per axis: every row's, or one for all
    sensor_pos: tuple[float, float, float]
    fixed: dict[int, Measurement]
    rejected: list[tuple[int, str]]  # (row, "row <i> (<id>): <reason>") of each bad row
    sigma_t: list[float] | float | None = None  # s: every row's time noise, one for all, none


_IDS = re.compile(r"[A-Za-z0-9_-]+(?:/[A-Za-z0-9_-]+)*")  # ids joined by "/" (not in a chunk)


def parse_scan_columns(sensor: str, payload: bytes,
                       noise: tuple[float, float, float, float]) -> ScanColumns:
    """`parse_scan` as columns: the same rows good, the same rejections
    (tests/test_scan.py), checked a column at a time."""
    ids, times, bad_t, scan, time_noise = _front(sensor, payload, noise)
    polar, width, n, cols = scan.bins()
    bad = scan.bad(polar, width, n, cols)
    if polar:
        names = ("r", "az", "el") if "el" in cols else ("r", "az")
        values = [cols[k] for k in names]
        sigmas: list[list[float] | float] = [cols.get(k, scan.eff[k])
                                             for k in NOISE[:len(names)]]
        dim = len(names)
    else:
        pos, dim = cols["pos"], width
        values = [pos[k::width] for k in range(width)]
        if "sigma" in cols:
            sigmas = [cols["sigma"]] * width
        else:
            s = scan.eff["sigma"]
            one = _axes(s, width) if type(s) is list else (s,) * width
            sigmas = list(one) if one is not None else [0.0] * width  # None: all rows bad
    fixed: dict[int, Measurement] = {}
    rejected: list[tuple[int, str]] = []
    suspects = bad | bad_t | time_noise[1]
    st = time_noise[0]
    if not _IDS.fullmatch("/".join(ids)) and n:
        suspects |= {i for i, k in enumerate(ids) if not CHUNK.fullmatch(k)}
    for i in sorted(suspects):
        m = scan.row(i, polar, cols) if i in bad else None
        reason = _reason(i, ids[i], m, times, bad_t, time_noise)
        if reason is not None:
            rejected.append((i, reason))
        elif m is not None:
            fixed[i] = m if st is None else replace(  # type: ignore[assignment]
                m, sigma_t=st[i] if isinstance(st, list) else st)
    out = {i for i, _ in rejected}
    good = [i for i in range(n) if i not in out] if out else list(range(n))
    return ScanColumns(sensor, n, good, [ids[i] for i in good] if out else ids,
                       times if times is not None else scan.t, dim, polar, values, sigmas,
                       scan.sensor_pos, fixed, rejected, st)  # type: ignore[arg-type]
