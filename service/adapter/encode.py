"""Bulk MessagePack encoding of the service's outputs from NumPy columns.

The bodies of many tracks at once: the numbers of every row are written by NumPy into
one buffer laid out as MessagePack (float 64 0xcb and int 64 0xd3, big-endian; fixarray
0x9n or array 16 0xdc), and each body is its row's slice followed by its own packed
strings and maps. Decoded, the maps equal what `wire.pack` gives for the same dicts
(tests/test_wire.py). Part of the Zenoh adapter: clients decode with `zenoh_track.wire`.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from typing import Any

import numpy as np

from ..wire import pack

Column = tuple[str, "np.ndarray | tuple[list[str], np.ndarray]"]


Write = tuple[int, int, int, int, int, bool]  # column, first value, count, offset, stride, int


def _layout(columns: Sequence[Column], entries: int) -> tuple[bytes, tuple[Write, ...]]:
    """The template of one row's body and where each column's numbers go in it (kept per
    shape of columns)."""
    shape = []
    for key, value in columns:
        fields, col = value if isinstance(value, tuple) else (None, value)
        shape.append((key, None if fields is None else tuple(fields),
                      col.shape[1] if col.ndim == 2 else None, col.dtype.kind in "iub"))
    return _layout_of(tuple(shape), entries)


@lru_cache(maxsize=64)
def _layout_of(shape: tuple[tuple[str, tuple[str, ...] | None, int | None, bool], ...],
               entries: int) -> tuple[bytes, tuple[Write, ...]]:
    """`_layout` of columns (key, fields, width (None: a vector), integer): the template
    and the writes (column j's values first..first+count at offset, offset + stride, ...:
    one strided write per run of values evenly spaced, as a vector's or an array's are)."""
    template, writes = pack_map_header(entries), []
    for j, (key, fields, width, integer) in enumerate(shape):
        template += pack(key)
        if fields is not None:  # a map of these fields, one number each
            template += pack_map_header(width)
        elif width is not None:
            template += bytes([0x90 | width]) if width < 16 else b"\xdc" + width.to_bytes(2, "big")
        offsets = []
        for k in range(max(width or 0, 1)):
            if fields is not None:
                template += pack(fields[k])
            template += (b"\xd3" if integer else b"\xcb") + bytes(8)
            offsets.append(len(template) - 8)
        first = 0
        while first < len(offsets):  # the runs of evenly spaced values
            end = first + 1
            stride = offsets[end] - offsets[first] if end < len(offsets) else 8
            while end < len(offsets) and offsets[end] - offsets[end - 1] == stride:
                end += 1
            writes.append((j, first, end - first, offsets[first], stride, integer))
            first = end
    return template, tuple(writes)


def pack_map_header(entries: int) -> bytes:
    return bytes([0x80 | entries]) if entries < 16 else b"\xde" + entries.to_bytes(2, "big")


def pack_rows(columns: Sequence[Column], tails: Sequence[bytes],
              tail_entries: int) -> list[bytes]:
    """One MessagePack map per row: the numeric `columns` ((N,) or (N, k) arrays, or
    (k field names, (N, k) array) for a map of numbers, in this key order) then the
    row's `tails` (packed key-value pairs, `tail_entries` of them).

    The rows are written into one (N, body) byte array: the template, the tails when all
    are as long (track ids of one width: each body is then one row's bytes), and each run of
    evenly spaced numbers of a column by one strided big-endian view (a few NumPy calls a
    column, not one per number)."""
    n = len(tails)
    if not n:
        return []
    template, writes = _layout(columns, len(columns) + tail_entries)
    size, tail = len(template), len(tails[0])
    whole = all(len(t) == tail for t in tails)  # the tails go into the array too
    width = size + tail if whole else size
    raw = np.empty((n, width), dtype=np.uint8)
    raw[:, :size] = np.frombuffer(template, dtype=np.uint8)
    if whole and tail:
        raw[:, size:] = np.frombuffer(b"".join(tails), dtype=np.uint8).reshape(n, tail)
    cols = [value[1] if isinstance(value, tuple) else value for _, value in columns]
    for j, first, count, offset, stride, integer in writes:
        col = cols[j]
        src = col[:, first:first + count] if col.ndim == 2 else col[:, None]
        np.ndarray((n, count), dtype=">i8" if integer else ">f8", buffer=raw, offset=offset,
                   strides=(width, stride))[...] = src
    if whole:
        return [row.tobytes() for row in raw]
    buf = raw.tobytes()
    return [buf[i:i + size] + t for i, t in zip(range(0, n * size, size), tails, strict=True)]


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
               sigma: np.ndarray, status: np.ndarray, instance: str | None = None) -> bytes:
    """The `frame` body {t, ids, pos, vel, sigma, status[, instance]} with `ids` already
    packed (it changes only when tracks come or go), the arrays as little-endian float64
    bins and `status` one byte per track (an index into wire.STATUSES): one `bytes.join`
    of the headers and the arrays' own buffers (at 100,000 tracks a frame is 7 MB: one
    copy of each part into a body that is not zeroed first; an array not already
    contiguous in the wire's type is converted first). `instance`: the liveliness name
    of the service that drew it, which clients merge the frames of several instances by
    (docs/protocol.md, "Several instances")."""
    parts: list[Any] = [pack_map_header(6 if instance is None else 7), pack("t"),
                        pack(float(t)), pack("ids"), ids]
    for key, col, dtype in (("pos", pos, "<f8"), ("vel", vel, "<f8"), ("sigma", sigma, "<f8"),
                            ("status", status, "u1")):
        col = np.ascontiguousarray(col, dtype=dtype)  # a no-op when it already is
        parts += (pack(key), _bin_header(col.nbytes), col.reshape(-1).view(np.uint8))
    if instance is not None:
        parts += (pack("instance"), pack(instance))
    return b"".join(parts)


def _bin_header(size: int) -> bytes:
    """MessagePack bin 8/16/32 header of `size` bytes."""
    if size < 1 << 8:
        return b"\xc4" + size.to_bytes(1, "big")
    if size < 1 << 16:
        return b"\xc5" + size.to_bytes(2, "big")
    return b"\xc6" + size.to_bytes(4, "big")


_TRACK_STRINGS = PackedStrings(("id", "model"))
_TRACK_IDS = PackedStrings(("id",))


def pack_tracks(t: np.ndarray, ids: Sequence[str], pos: np.ndarray, vel: np.ndarray,
                x: np.ndarray, p: np.ndarray, models: Sequence[Any], nis: np.ndarray,
                updates: np.ndarray) -> list[bytes]:
    """The `tracks/<id>` bodies of many tracks: {t, pos, vel, x, P (row-major), nis,
    updates, id, model}; a model is a name or a map (IMM mode probabilities)."""
    columns: list[Column] = [("t", t), ("pos", pos), ("vel", vel), ("x", x), ("P", p),
                             ("nis", nis), ("updates", updates)]
    mu = getattr(models, "mu", None)  # imm.ModeProbabilities: one map layout for all
    if mu is not None:
        return pack_rows([*columns, ("model", (list(models.names), mu))],  # type: ignore
                         [_TRACK_IDS((i,)) for i in ids], 1)
    tails = [_TRACK_STRINGS((i, m)) if isinstance(m, str) else
             pack("id") + pack(i) + pack("model") + pack(m)
             for i, m in zip(ids, models, strict=True)]
    return pack_rows(columns, tails, 2)


def _f64(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def pack_states(st: Any) -> bytes:
    """The batched `states` body of one block of updated tracks (`tracking.States`):
    {t, ids, n, pos, vel, x, P, nis, updates} with each numeric field a bin of
    little-endian float64, row-major ((N,), (N, 3), (N, n), (N, n * n)), plus `model`
    (the one model's name) or `modes` and `mu` ((N, M) mode probabilities)."""
    models = st.models
    body: dict[str, Any] = {"t": _f64(st.t), "ids": list(st.ids), "n": int(st.x.shape[1]),
                            "pos": _f64(st.pos), "vel": _f64(st.vel), "x": _f64(st.x),
                            "P": _f64(st.p), "nis": _f64(st.nis), "updates": _f64(st.updates)}
    mu = getattr(models, "mu", None)  # imm.ModeProbabilities
    if mu is not None:
        body["modes"] = list(models.names)
        body["mu"] = _f64(mu)
    elif models:
        body["model"] = models[0] if len(set(models)) == 1 else list(models)
    return pack(body)
