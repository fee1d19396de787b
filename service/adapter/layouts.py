"""A worker's take of single measurements read as NumPy columns of their bytes, when every
message is laid out byte for byte like the first and that is the common form with each
value a msgpack float64 (what one feed sends: the same keys in the same order, `seq` of
one width; `wire.singles.value_offsets` finds where the values are).

Bytes equal outside the values decode to the same map, so this gives what
`wire.parse_singles` gives on the same messages (tests/test_singles.py): the bytes
outside the values are compared with the first message's as one array, the values read
by one structured dtype (big-endian float64 at their offsets) and checked as columns
against `wire.keys.BOUNDS`. Anything else (another layout in the take, a value out of
bounds, an id that is not a chunk) returns None, and the caller takes the wire's
message-by-message path for the whole take.
"""

from __future__ import annotations

import numpy as np

from ..wire import Singles
from ..wire.keys import BOUNDS, MAX_SEQ
from ..wire.scans import _IDS, ScanColumns
from ..wire.singles import FIELDS, value_offsets

LAYOUT_MIN = 8  # messages in a take from which this is tried (fewer: decoding each is cheaper)
HELD = 64  # layouts remembered (a feed sends one or a few)
_READERS: dict[bytes, tuple[np.ndarray, np.ndarray, np.dtype, int | None]] = {}
_BOUNDS = [BOUNDS[name] for name in FIELDS]


def by_layout(sensors: list[str], targets: list[str], payloads: list[bytes]
              ) -> Singles | None:
    """The messages (sensor, target, payload)[i] checked as columns of their bytes when all
    are laid out like the first and every one is good; else None."""
    n = len(payloads)
    if n < LAYOUT_MIN:
        return None
    first = payloads[0]
    size = len(first)
    if len(set(map(len, payloads))) != 1:
        return None
    reader = _reader(first)
    if reader is None:
        return None
    fixed_at, fixed, dtype, fixint = reader
    joined = b"".join(payloads)
    raw = np.frombuffer(joined, np.uint8).reshape(n, size)
    if not (raw[:, fixed_at] == fixed).all():  # a byte outside the values differs
        return None
    rec = np.frombuffer(joined, dtype)
    seqs: list[int | None] = [None] * n
    if "seq" in dtype.names:
        if fixint is not None and raw[:, fixint].max() > 0x7F:  # not a positive fixint
            return None
        s = rec["seq"]
        if s.max() > MAX_SEQ:
            return None
        seqs = s.tolist()
    cols = [rec[name].astype(float) for name in FIELDS]
    for col, (lo, hi) in zip(cols, _BOUNDS, strict=True):
        with np.errstate(invalid="ignore"):
            if not (np.isfinite(col.sum()) and col.min() >= lo and col.max() <= hi):
                return None  # a NaN, an infinity (or an overflow) or a value out of bounds
    if not (_IDS.fullmatch("/".join(targets)) and _IDS.fullmatch("/".join(set(sensors)))):
        return None
    t, *vals = cols
    return Singles([(list(range(n)), ScanColumns(
        sensors[0], n, list(range(n)), list(targets), t, 3, True, vals[:3], vals[3:],
        (0.0, 0.0, 0.0), {}, []))], [], seqs)


def _reader(first: bytes) -> tuple[np.ndarray, np.ndarray, np.dtype, int | None] | None:
    """For messages laid out like `first`: the offsets of its bytes outside the values and
    those bytes, the structured dtype of its values, and the offset of a fixint seq (whose
    byte is its value) or None. Remembered per layout."""
    found = value_offsets(first)
    if found is None:
        return None
    at, seq = found
    cuts = [(o, 8, name) for name, o in at.items()]
    if seq is not None:
        cuts.append((seq[0], seq[1] or 1, "seq"))
    shape = bytearray(first)  # the layout: the message with its values zeroed
    for o, width, _ in cuts:
        shape[o:o + width] = bytes(width)
    key = bytes(shape)
    got = _READERS.get(key)
    if got is None:
        inside = np.zeros(len(first), dtype=bool)
        for o, width, _ in cuts:
            inside[o:o + width] = True
        fixed_at = np.flatnonzero(~inside)
        fixed = np.frombuffer(first, np.uint8)[fixed_at].copy()
        dtype = np.dtype({"names": [name for _, _, name in cuts],
                          "formats": [">f8" if name != "seq" else f">u{width}"
                                      for _, width, name in cuts],
                          "offsets": [o for o, _, _ in cuts], "itemsize": len(first)})
        got = (fixed_at, fixed, dtype, seq[0] if seq is not None and not seq[1] else None)
        if len(_READERS) >= HELD:
            _READERS.clear()
        _READERS[key] = got
    return got
