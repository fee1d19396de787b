"""Checks of `<ns>/scan/<sensor>` (contract 1.1): many labelled measurements in one
columnar message, bytes in, checked records out (docs/protocol.md §3.4).

`{t, ids: [str...], r, az[, el] | pos, sr?, saz?, sel?, sigma?, sensor_pos?, dim?}`: `t` a
float (all rows) or a bin of N little-endian float64, `r`, `az`, `el` bins of N float64,
`pos` a bin of (N, 2) or (N, 3) float64, each noise field a float or a bin of N float64.
Row i means exactly what `meas/<sensor>/<ids[i]>` with those values would mean: the
values are checked a column at a time (`plots.bad_rows`), and a row with a bad value goes
through the reference check `parse_full` for its reason. A bad row is rejected alone; a
scan that cannot be read as a whole (unequal lengths, unreadable bins, no `ids`) raises
`Rejected`.
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass

from .codec import Rejected, decode_map, pack
from .keys import CHUNK, MAX_SCAN_BYTES
from .messages import Measurement, parse_full
from .plots import _SET, _limit, _Scan, bad_rows


@dataclass(frozen=True, slots=True)
class LabelledScan:
    """One checked batched scan: its good rows in order, and why the others were set aside."""

    sensor: str
    measurements: list[Measurement]  # the good rows, in order
    rejected: list[tuple[int, str]]  # (row, "row <i> (<id>): <reason>") of each bad row


def parse_scan(sensor: str, payload: bytes,
               noise: tuple[float, float, float, float]) -> LabelledScan:
    """Check one `<ns>/scan/<sensor>` payload (`noise`: the service's default noise)."""
    msg = decode_map(payload, MAX_SCAN_BYTES)
    ids = msg.get("ids")
    if not isinstance(ids, list) or not all(type(i) is str for i in ids):
        raise Rejected("batched scan needs 'ids', a list of target ids (strings)")
    n = len(ids)
    _limit(n)
    if "t" not in msg:
        raise Rejected("missing required field 't'")
    t = msg["t"]
    times: list[float] | None = None
    if isinstance(t, bytes):
        if len(t) != 8 * n:
            raise Rejected(f"bin 't' has {len(t)} bytes, not {n} float64 (one per id)")
        times = list(struct.unpack(f"<{n}d", t))
        head_t = next((v for i, v in enumerate(times) if i not in bad_rows(times, "t")), 0.0)
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
    out, _ = _Scan(sensor, ref.t, ref.sensor_pos, msg, head, noise).columns()
    bad_t = bad_rows(times, "t") if times is not None else set()
    good: list[int] = []
    rejected: list[tuple[int, str]] = []
    for i, (target, m) in enumerate(zip(ids, out, strict=True)):
        if type(m) is str:
            reason = m
        elif not CHUNK.fullmatch(target):
            reason = f"target chunk '{target}' must be letters, digits, '-' or '_'"
        elif i in bad_t:
            reason = f"field 't' is not finite or out of bounds ({times[i]})"
        else:
            good.append(i)
            continue
        rejected.append((i, f"row {i} ({target[:64]}): {reason}"))
    records = [out[i] for i in good]
    deque(map(_SET["target"], records, [ids[i] for i in good]), 0)
    if times is not None:
        deque(map(_SET["t"], records, [times[i] for i in good]), 0)
    return LabelledScan(sensor, records, rejected)  # type: ignore[arg-type]
