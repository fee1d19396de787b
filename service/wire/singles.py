"""Checks of many single `<ns>/meas/<sensor>/<target>` messages at once: what a tracker's
worker takes from its channel in one go, as columns, without a record per message.

The same messages good, with the same values and the same rejections, as
`parse_measurement` on each (tests/test_singles.py). The common form (a 3-D polar
measurement with every field a float: `{t, r, az, el, sr, saz, sel[, seq]}`) is checked a
column at a time (`plots.bad_rows`); a message of another form, or one a column check
flags, goes through `parse_measurement` alone and either joins the columns as a record
(`ScanColumns.fixed`) or is rejected with that check's reason.

Faster still, a take of one byte layout (what one feed sends) is read as NumPy columns
of its bytes by the service (`service.layouts`, from `value_offsets`): this package loads
no NumPy.
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import itemgetter

import msgpack

from .codec import Rejected
from .keys import CHUNK, MAX_MEAS_BYTES, MAX_SEQ
from .messages import POLAR_3D, Measurement, parse_measurement
from .plots import bad_rows
from .scans import _IDS, ScanColumns

FIELDS = _FIELDS = ("t", "r", "az", "el", "sr", "saz", "sel")  # the common form
_GET = itemgetter(*_FIELDS)
_FLOAT = {float}
_NAMES = {f.encode(): f for f in (*_FIELDS, "seq")}
_UINT = {0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8}  # msgpack uint 8/16/32/64: value bytes


@dataclass
class Singles:
    """Single messages checked together: the good ones as columns, one part per run of
    messages of one dimension (`parts`: each part's message indices and columns), the
    rejected ones with their reasons, and each message's `seq` (None: absent or rejected)."""

    parts: list[tuple[list[int], ScanColumns]]
    rejected: list[tuple[int, str]]
    seqs: list[int | None]


def _map(payload: bytes) -> object:
    """The decoded payload when it may be of the common form, else None."""
    if len(payload) > MAX_MEAS_BYTES:
        return None
    try:
        return msgpack.unpackb(payload)
    except Exception:  # malformed: the full check names the problem
        return None


def parse_singles(sensors: list[str], targets: list[str], payloads: list[bytes],
                  noise: tuple[float, float, float, float]) -> Singles:
    """Check the messages (sensor, target, payload)[i], in order (`noise`: the service's
    default noise for a message that gives none)."""
    n = len(payloads)
    msgs = list(map(_map, payloads))
    fast = [i for i, m in enumerate(msgs)  # the 7 fields, and perhaps seq
            if type(m) is dict and POLAR_3D.issuperset(m) and len(m) - ("seq" in m) == 7]
    rows = [_GET(msgs[i]) for i in fast]
    cols = list(zip(*rows, strict=True)) if rows else [()] * len(_FIELDS)
    suspect: set[int] = set()  # positions in `fast` that need the full check
    for name, col in zip(_FIELDS, cols, strict=True):
        if set(map(type, col)) - _FLOAT:
            suspect |= {j for j, v in enumerate(col) if type(v) is not float}
        else:
            suspect |= bad_rows(list(col), name)
    seqs: list[int | None] = [None] * n
    for j, i in enumerate(fast):
        s = msgs[i].get("seq")  # type: ignore[union-attr]
        if s is not None:
            if type(s) is int and 0 <= s <= MAX_SEQ:
                seqs[i] = s
            else:
                suspect.add(j)
    if not (_IDS.fullmatch("/".join(targets)) and _IDS.fullmatch("/".join(set(sensors)))):
        suspect |= {j for j, i in enumerate(fast)
                    if not (CHUNK.fullmatch(sensors[i]) and CHUNK.fullmatch(targets[i]))}
    good = dict.fromkeys(i for j, i in enumerate(fast) if j not in suspect)
    records: dict[int, Measurement] = {}
    rejected: list[tuple[int, str]] = []
    for i in range(n):
        if i in good:
            continue
        try:
            m = records[i] = parse_measurement(sensors[i], targets[i], payloads[i], noise)
            seqs[i] = m.seq
        except Rejected as exc:
            rejected.append((i, str(exc)))
            seqs[i] = None
    at = {i: j for j, i in enumerate(fast)}
    return Singles(_parts(n, good, records, at, cols, sensors, targets), rejected, seqs)


def _parts(n: int, good: dict[int, None], records: dict[int, Measurement],
           at: dict[int, int], cols: list[tuple], sensors: list[str], targets: list[str]
           ) -> list[tuple[list[int], ScanColumns]]:
    """The good messages as columns, one part per run of one dimension."""
    out: list[tuple[list[int], ScanColumns]] = []
    run: list[int] = []
    dim = 0
    for i in range(n):
        d = 3 if i in good else (records[i].dim if i in records else 0)
        if not d:
            continue
        if run and d != dim:
            out.append((run, _columns(run, dim, good, records, at, cols, sensors, targets)))
            run = []
        run.append(i)
        dim = d
    if run:
        out.append((run, _columns(run, dim, good, records, at, cols, sensors, targets)))
    return out


def _columns(run: list[int], dim: int, good: dict[int, None], records: dict[int, Measurement],
             at: dict[int, int], cols: list[tuple], sensors: list[str], targets: list[str]
             ) -> ScanColumns:
    """One part: the columns of the common-form messages, the records of the others."""
    k = len(run)
    fixed = {j: records[i] for j, i in enumerate(run) if i not in good}
    if not fixed and len(run) == len(at) and dim == 3:  # every message of the common form
        t, *vals = (list(c) for c in cols)
    else:
        def column(c: int) -> list[float]:
            col = cols[c]
            return [col[at[i]] if i in good else 0.0 for i in run]
        t = [records[i].t if i in records else cols[0][at[i]] for i in run]
        vals = [column(c) for c in range(1, 7)] if dim == 3 else [[0.0] * k] * (2 * dim)
    values, sigmas = vals[:dim], vals[dim:]
    return ScanColumns(sensors[run[0]], k, list(range(k)), [targets[i] for i in run], t, dim,
                       True, values, sigmas, (0.0, 0.0, 0.0), fixed, [])


def value_offsets(p: bytes) -> tuple[dict[str, int], tuple[int, int] | None] | None:
    """Where the values are in a message of the common form laid out as msgpack packs it:
    a fixmap of the 7 fields (fixstr keys, each value a float64) and perhaps `seq` (a
    positive fixint or an uint): each field's value offset and seq's (offset, width; width
    0 for a fixint, whose value is its byte). None for any other message."""
    if not p or p[0] not in (0x87, 0x88) or len(p) > MAX_MEAS_BYTES:
        return None
    at: dict[str, int] = {}
    seq = None
    pos, end = 1, len(p)
    for _ in range(p[0] & 0x0F):
        if pos >= end or not 0xA0 <= p[pos] <= 0xBF:
            return None
        size = p[pos] & 0x1F
        name = _NAMES.get(p[pos + 1:pos + 1 + size])
        pos += 1 + size
        if name is None or name in at or pos >= end or (name == "seq" and seq is not None):
            return None
        if name != "seq":
            if p[pos] != 0xCB:
                return None
            at[name], pos = pos + 1, pos + 9
        elif p[pos] <= 0x7F:
            seq, pos = (pos, 0), pos + 1
        elif p[pos] in _UINT:
            seq = (pos + 1, _UINT[p[pos]])
            pos += 1 + seq[1]
        else:
            return None
    return (at, seq) if pos == end and len(at) == 7 else None
