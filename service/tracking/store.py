"""The track store: every track's state and covariance in stacked arrays.

Tracks with the same state layout (dimension 2 or 3, model order) share one
`TrackArrays`: predicting all of them, or updating a batch of them, is one vectorised
operation over their rows. A track's row stays its own until it is deleted; freed rows
are reused. Every other per-row field lives there too, as a named `Column` that a
component declares: the filter's (`Updater.fields`), the track life of unlabelled tracks
(`life.LIFE_COLUMNS`) and the display state's (`display.DISPLAY_COLUMNS`), all grown
together with the rows.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

# shape codes of per-row columns: "" scalar, "n" state, "nn" covariance, "d" position,
# "dd" position covariance, "oo" derivative by derivative (order x order)
SHAPE_CODES = ("", "n", "nn", "d", "dd", "oo")


@dataclass(frozen=True)
class Column:
    """One per-row field of a layout: the shape of a row (a shape code, with a leading
    axis of `modes` when given), its dtype, whether a row given to a new track starts at
    zero (`fresh`; else its owner sets it) and whether a checkpoint keeps it (`saved`;
    else its owner makes it again from the saved ones)."""

    code: str = ""
    modes: int | None = None
    dtype: type = float
    fresh: bool = False
    saved: bool = True

    @classmethod
    def of(cls, spec: Column | tuple) -> Column:
        """A column, or a filter's (shape code, modes) pair (`Updater.fields`)."""
        return spec if isinstance(spec, Column) else cls(*spec)


# what every layout has: the filtered state, its times, the NIS and the update count
CORE = {"x": Column("n"), "p": Column("nn"), "t": Column(), "t_first": Column(),
        "nis": Column(), "updates": Column(dtype=np.int64), "alive": Column(dtype=bool,
                                                                              saved=False)}


class Columns:
    """Named arrays with one row per track slot, grown together: `shapes` maps a name to
    the shape of one row (`dtypes` to its dtype, float by default)."""

    def __init__(self, shapes: dict[str, tuple[int, ...]],
                 dtypes: dict[str, type] | None = None, capacity: int = 0) -> None:
        self.shapes = dict(shapes)
        self.dtypes = dtypes or {}
        self.capacity = 0
        for name, shape in self.shapes.items():
            setattr(self, name, np.zeros((0, *shape), dtype=self.dtypes.get(name, float)))
        self.grow(capacity)

    def grow(self, capacity: int) -> None:
        """At least `capacity` rows; existing rows keep their values, new rows are zero."""
        if capacity <= self.capacity:
            return
        for name, shape in self.shapes.items():
            old = getattr(self, name)
            grown = np.zeros((capacity, *shape), dtype=old.dtype)
            grown[:self.capacity] = old
            setattr(self, name, grown)
        self.capacity = capacity

    def __getattr__(self, name: str) -> np.ndarray:
        """Only for what is not a column (they are attributes): says so, and tells type
        checkers that a column read by name is an array (`estimation.filters.Rows`)."""
        raise AttributeError(f"no per-row column {name!r}")


class TrackArrays(Columns):
    """Tracks of one layout: the `CORE` columns (states x (cap, n), covariances p
    (cap, n, n), the time of the last update t, the first update t_first, the update
    count, the last NIS, whether a row is a live track) and the `columns` its users
    declared."""

    def __init__(self, dim: int, order: int, columns: Mapping[str, Column | tuple] | None = None,
                 capacity: int = 64) -> None:
        self.dim, self.order, self.n = dim, order, dim * order
        n = self.n
        codes = dict(zip(SHAPE_CODES, ((), (n,), (n, n), (dim,), (dim, dim), (order, order)),
                         strict=True))
        spec = {**CORE, **{k: Column.of(v) for k, v in (columns or {}).items()}}
        shapes = {name: ((c.modes,) if c.modes else ()) + codes[c.code]
                  for name, c in spec.items()}
        self.saved = [name for name, c in spec.items() if c.saved]
        self.fresh = [name for name, c in spec.items() if c.fresh]
        self.ids: list[str | None] = []
        self.free: list[int] = []
        self._live: tuple[np.ndarray, list[str]] | None = None
        super().__init__(shapes, {name: c.dtype for name, c in spec.items()}, capacity)

    def grow(self, capacity: int) -> None:
        old = self.capacity
        super().grow(capacity)
        self.ids.extend([None] * (self.capacity - old))
        self.free.extend(range(self.capacity - 1, old - 1, -1))

    def add(self, track_ids: Sequence[str]) -> np.ndarray:
        """Rows for new tracks (freed rows first, lowest first), their `fresh` columns
        zero."""
        k = len(track_ids)
        if len(self.free) < k:
            self.grow(max(2 * self.capacity, self.capacity + k))
        taken = self.free[len(self.free) - k:][::-1]
        del self.free[len(self.free) - k:]
        for row, track_id in zip(taken, track_ids, strict=True):
            self.ids[row] = track_id
        rows = np.array(taken, dtype=int)
        self.alive[rows] = True
        for name in self.fresh:
            getattr(self, name)[rows] = 0
        self._live = None
        return rows

    def remove(self, rows: Sequence[int]) -> None:
        for row in rows:
            self.ids[row] = None
        self.alive[np.asarray(rows, dtype=int)] = False
        self.free.extend(rows)
        self._live = None

    def live(self) -> tuple[np.ndarray, list[str]]:
        """Rows of the live tracks and their ids, cached until a track comes or goes
        (every display frame asks)."""
        if self._live is None:
            rows = self.alive.nonzero()[0]
            ids = self.ids
            self._live = (rows, [ids[i] for i in rows.tolist()])  # type: ignore[misc]
        return self._live

    def rows(self) -> np.ndarray:
        return self.live()[0]


@dataclass
class States:
    """Filtered states of tracks of one layout, as columns: the `tracks/<id>` bodies."""

    ids: list[str]
    t: np.ndarray  # (N,)
    pos: np.ndarray  # (N, 3), zero-padded for 2-D tracks
    vel: np.ndarray  # (N, 3)
    x: np.ndarray  # (N, n)
    p: np.ndarray  # (N, n * n), row-major
    models: Sequence  # per track: the model's name, or a map (imm.ModeProbabilities)
    nis: np.ndarray  # (N,)
    updates: np.ndarray  # (N,) int

    def body(self, i: int) -> dict:
        return {"t": float(self.t[i]), "id": self.ids[i], "pos": self.pos[i].tolist(),
                "vel": self.vel[i].tolist(), "x": self.x[i].tolist(), "P": self.p[i].tolist(),
                "model": self.models[i], "nis": float(self.nis[i]),
                "updates": int(self.updates[i])}

    def select(self, rows: list[int]) -> States:
        """The tracks at `rows` (indices) only."""
        r = np.asarray(rows, dtype=int)
        take = getattr(self.models, "take", None)  # IMM mode probabilities: as an array
        return States([self.ids[i] for i in rows], self.t[r], self.pos[r], self.vel[r],
                      self.x[r], self.p[r], take(r) if take else [self.models[i] for i in rows],
                      self.nis[r], self.updates[r])


class TrackStore:
    """All tracks, keyed by id: one `TrackArrays` per dimension, all of one model order
    (the filter's), with the filter's per-row fields (`extra`) and the other components'
    (`columns`)."""

    def __init__(self, order: int, extra: Mapping[str, Column | tuple] | None = None,
                 columns: Mapping[str, Column] | None = None) -> None:
        self.order, self.extra = order, dict(extra or {})
        self.columns: dict[str, Column | tuple] = {**(columns or {}), **self.extra}
        self.layouts: dict[int, TrackArrays] = {}
        self.where: dict[str, tuple[TrackArrays, int]] = {}

    def __len__(self) -> int:
        return len(self.where)

    def __contains__(self, track_id: str) -> bool:
        return track_id in self.where

    def layout(self, dim: int) -> TrackArrays:
        if dim not in self.layouts:
            self.layouts[dim] = TrackArrays(dim, self.order, self.columns)
        return self.layouts[dim]

    def add_many(self, track_ids: Sequence[str], dim: int) -> tuple[TrackArrays, np.ndarray]:
        """New tracks of one dimension: their layout and rows."""
        arrays = self.layout(dim)
        rows = arrays.add(track_ids)
        where = self.where
        for track_id, row in zip(track_ids, rows.tolist(), strict=True):
            where[track_id] = (arrays, row)
        return arrays, rows

    def remove(self, ids: Iterable[str]) -> None:
        pop = self.where.pop
        gone = [pop(track_id) for track_id in ids]
        if len(self.layouts) == 1 and gone:  # one layout: all its rows at once
            gone[0][0].remove([row for _, row in gone])
            return
        by_layout: dict[int, tuple[TrackArrays, list[int]]] = {}
        for arrays, row in gone:
            by_layout.setdefault(id(arrays), (arrays, []))[1].append(row)
        for arrays, rows in by_layout.values():
            arrays.remove(rows)

    def rename(self, old: str, new: str) -> None:
        """Track `old` goes on as `new` (an id not in the store)."""
        arrays, row = self.where.pop(old)
        arrays.ids[row] = new
        arrays._live = None
        self.where[new] = (arrays, row)

    def states(self, arrays: TrackArrays, rows: Sequence[int] | np.ndarray,
               labels: Sequence, x: np.ndarray | None = None, p: np.ndarray | None = None
               ) -> States:
        """The filtered states of rows of one layout, as columns (`labels`: the filter's
        model label of each row; x (N, n), P (N, n, n): their states and covariances as
        new arrays, if the caller has them, else taken from the store)."""
        r = np.asarray(rows, dtype=int)
        d, n = arrays.dim, len(r)
        if x is None or p is None:
            x, p = arrays.x[r], arrays.p[r]
        pos, vel = np.zeros((n, 3)), np.zeros((n, 3))
        pos[:, :d], vel[:, :d] = x[:, :d], x[:, d:2 * d]
        ids = arrays.ids
        return States([ids[i] for i in r.tolist()], arrays.t[r], pos, vel,  # type: ignore[misc]
                      x, p.reshape(n, -1), labels, arrays.nis[r], arrays.updates[r])
