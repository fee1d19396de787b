"""The track table as bytes and back: a service restarted from its state file has its
tracks again (docs/operations.md).

A checkpoint is a NumPy `.npz` archive (no pickles: `np.load(allow_pickle=False)`):
`meta` holds a JSON header (format name, `VERSION`, the filter and its per-row fields,
the tracker's small dictionaries and the adapter's own `extra`), and each layout of the
store is saved as its live rows only, `<dim>/ids` and `<dim>/<field>` per column. A file
of another format, version or filter, or whose arrays are malformed or not finite, is
refused whole with a `CheckpointError` that says why; nothing is changed then.

What comes back is each track's filtered state at the time of its last update: the
display predicts it to the instants after the restart like any other coasting track, so
the gap shows as age, grown sigma and, when long enough, the `coasting` status.
"""

from __future__ import annotations

import io
import json
import zipfile
from typing import TYPE_CHECKING, Any

import numpy as np

from ..wire import CHUNK
from .store import TrackArrays

if TYPE_CHECKING:
    from .tracker import Tracker

FORMAT = "zenoh-track-service checkpoint"
VERSION = 1
FINITE = ("x", "p", "t", "t_first")  # what the picture is drawn from (filters may keep NaN
# in their own fields, e.g. the VDF's unfilled history)


class CheckpointError(ValueError):
    """A checkpoint that cannot be restored, with the reason."""


def header(tracker: Tracker) -> dict[str, Any]:
    """What a checkpoint must agree on with the tracker that reads it."""
    store = tracker.store
    return {"format": FORMAT, "version": VERSION, "filter": tracker.filter.name,
            "order": store.order, "fields": {k: list(v) for k, v in sorted(store.extra.items())}}


def template(tracker: Tracker, dim: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """Each per-row column of a layout: (shape of a row, dtype kind)."""
    lay = TrackArrays(dim, tracker.store.order, tracker.store.columns, capacity=0)
    return {k: (lay.shapes[k], getattr(lay, k).dtype.kind) for k in lay.saved}


def capture(tracker: Tracker, extra: dict[str, Any] | None = None
            ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """A copy of what a checkpoint holds (the header, and the live rows of every layout
    as arrays), quick enough for the thread that owns the tracker; `encode` makes the
    bytes of it on any thread. `extra`: the adapter's own JSON-serialisable state."""
    meta = header(tracker)
    meta.update(**tracker.memory(), extra=extra or {}, layouts=sorted(tracker.store.layouts))
    arrays: dict[str, np.ndarray] = {}
    for dim, lay in tracker.store.layouts.items():
        rows, ids = lay.live()
        arrays[f"{dim}/ids"] = np.array(ids, dtype=str)
        for name in lay.saved:  # not `alive` (every saved row is a live track) nor what
            arrays[f"{dim}/{name}"] = getattr(lay, name)[rows]  # the display makes again
    return json.loads(json.dumps(meta)), arrays


def encode(captured: tuple[dict[str, Any], dict[str, np.ndarray]]) -> bytes:
    """The bytes of an .npz archive of a `capture`."""
    meta, arrays = captured
    buf = io.BytesIO()
    np.savez(buf, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    return buf.getvalue()


def dump(tracker: Tracker, extra: dict[str, Any] | None = None) -> bytes:
    """The tracker's tracks (live rows of every layout), the track numbers given per
    sensor and the last sensor of each labelled track, with the adapter's `extra`
    (JSON-serialisable), as the bytes of an .npz archive."""
    return encode(capture(tracker, extra))


def load(tracker: Tracker, data: bytes) -> dict[str, Any]:
    """Put the checkpoint's tracks into `tracker` (which must hold none) and return the
    adapter's `extra` and the header. Raises CheckpointError, changing nothing, when the
    bytes are not a checkpoint this tracker can take."""
    if len(tracker.store):
        raise CheckpointError("the tracker already holds tracks")
    meta, tables = _read(data)
    want = header(tracker)
    for key in ("format", "version", "filter", "order", "fields"):
        if meta.get(key) != want[key]:
            raise CheckpointError(f"{key} is {meta.get(key)!r}, this service needs "
                                  f"{want[key]!r}")
    seen: set[str] = set()
    for dim, (ids, cols) in tables.items():
        _check(dim, ids, cols, tracker, seen)
    numbers, last = meta.get("numbers", {}), meta.get("last", {})
    if not (_str_map(numbers, int) and _str_map(last, str)):
        raise CheckpointError("malformed track numbers or last sensors")
    for dim, (ids, cols) in tables.items():
        tracker.restore(dim, ids, cols)
    tracker.recall({"numbers": numbers, "last": last})
    return meta


def _read(data: bytes) -> tuple[dict, dict[int, tuple[list[str], dict[str, np.ndarray]]]]:
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            files = {k: z[k] for k in z.files}
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise CheckpointError(f"not a checkpoint archive ({type(exc).__name__}: "
                              f"{str(exc)[:120]})") from None
    raw = files.pop("meta", None)
    try:
        meta = json.loads(bytes(raw).decode()) if raw is not None else None
    except (ValueError, TypeError):
        meta = None
    if not isinstance(meta, dict):
        raise CheckpointError("no readable header")
    if meta.get("format") != FORMAT:
        raise CheckpointError(f"format is {meta.get('format')!r}, not {FORMAT!r}")
    layouts = meta.get("layouts")
    if not isinstance(layouts, list) or not all(d in (2, 3) for d in layouts):
        raise CheckpointError("malformed layout list")
    tables = {}
    for dim in layouts:
        ids = files.pop(f"{dim}/ids", None)
        if ids is None or ids.ndim != 1 or ids.dtype.kind != "U":
            raise CheckpointError(f"layout {dim}: missing or malformed ids")
        cols = {k.split("/", 1)[1]: files.pop(k) for k in list(files)
                if k.startswith(f"{dim}/")}
        tables[dim] = (ids.tolist(), cols)
    if files:
        raise CheckpointError(f"unexpected arrays {sorted(files)[:3]}")
    return meta, tables


def _check(dim: int, ids: list[str], cols: dict[str, np.ndarray], tracker: Tracker,
           seen: set[str]) -> None:
    """Every column present with its shape and kind, every value finite, ids valid."""
    lay = template(tracker, dim)
    n = len(ids)
    for i in ids:
        if not CHUNK.fullmatch(i) or i in seen:
            raise CheckpointError(f"layout {dim}: bad or repeated track id {i[:40]!r}")
        seen.add(i)
    names = set(lay)
    if set(cols) != names:
        raise CheckpointError(f"layout {dim}: columns {sorted(set(cols) ^ names)} differ")
    for name, (shape, kind) in ((k, lay[k]) for k in names):
        col = cols[name]
        if col.shape != (n, *shape) or col.dtype.kind != kind:
            raise CheckpointError(f"layout {dim}: column {name} has shape {col.shape} "
                                  f"{col.dtype}, expected {(n, *shape)} of kind {kind}")
        if name in FINITE and not np.isfinite(col).all():
            raise CheckpointError(f"layout {dim}: column {name} is not finite")


def _str_map(value: Any, kind: type) -> bool:
    return isinstance(value, dict) and all(isinstance(k, str) and isinstance(v, kind)
                                           for k, v in value.items())
