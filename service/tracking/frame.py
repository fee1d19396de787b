"""The frames' fast form: every live track of a layout drawn at one instant (plain
prediction, no blending, no lag: the default display), from the display's columns kept
batch-last between frames.

A frame reads, per track, its filtered state x, its time t, the six distinct sums of its
covariance's axis blocks and, for its status, the age beyond which it coasts and whether
it is established. Those change only when the track is updated or started, so
`FrameColumns` keeps them batch-last (one contiguous row per quantity, one column per
store row): the display's `initiate` and `update` hand it the new states and axis sums
as they make them (`take`), and a frame reads from the store only the time and status of
the rows whose time differs from the one kept (all of a row that changed without the
display: the safety net). A frame then reads contiguous columns a chunk at a time
instead of every row's 9 + 9 numbers strided.
`DisplayState.snapshot` uses it; `display.predicted_at` and `status.status_codes` are the
plain forms it equals (tests/test_frame.py): the positions, velocities, ages and status
codes to the bit, the sigmas to 1e-12 relative (the noise term's |dt|^6 is a product
here, not the 25 ns `pow` per row that `predicted_at` calls).
"""

from __future__ import annotations

import numpy as np

from ..estimation import blocks, jit
from .status import COASTING
from .store import Columns, TrackArrays

CHUNK = 16384  # columns per pass (measured best of 2,048-32,768 at 10,000 and 100,000)
# the distinct entries of the (order x order) axis sums, row-major flat indices
AXIS_ENTRIES = {3: (0, 1, 2, 4, 5, 8), 2: (0, 1, 3)}


class FrameColumns:
    """One layout's frame inputs, batch-last, by store row: x (n, cap), t (cap,), the
    axis sums' distinct entries (k, cap; A01 doubled, A22 quartered), the coasting limit
    coast_after x the mean interval between updates (cap,) and whether the track is
    established (cap,)."""

    def __init__(self, arrays: TrackArrays, coast_after: float) -> None:
        self.order, self.dim, self.coast_after = arrays.order, arrays.dim, coast_after
        self.entries = AXIS_ENTRIES[arrays.order]
        self.x = np.zeros((arrays.n, 0))
        self.t = np.zeros(0)
        self.a = np.zeros((len(self.entries), 0))
        self.limit = np.zeros(0)
        self.base = np.zeros(0, dtype=np.uint8)
        self.taken = np.zeros(0, dtype=bool)  # x and a given by `take`, time not read
        self.rows: np.ndarray | None = None  # the live rows last drawn, and their span
        self.index: slice | np.ndarray = slice(0, 0)

    def grow(self, capacity: int) -> None:
        old = len(self.t)
        if capacity <= old:
            return
        for name in ("x", "a"):
            a = getattr(self, name)
            grown = np.zeros((len(a), capacity))
            grown[:, :old] = a
            setattr(self, name, grown)
        self.t = np.concatenate([self.t, np.full(capacity - old, np.nan)])  # not read yet
        self.limit = np.concatenate([self.limit, np.zeros(capacity - old)])
        self.base = np.concatenate([self.base, np.zeros(capacity - old, np.uint8)])
        self.taken = np.concatenate([self.taken, np.zeros(capacity - old, bool)])

    def take(self, rows: np.ndarray, x: np.ndarray, axis_cov: np.ndarray) -> None:
        """Rows about to take states x (k, n) with covariance axis sums (k, order, order)
        (the display's `initiate` and `update`): kept now, their time and status read at
        the next frame."""
        self.x[:, rows] = x.T
        self.a[:, rows] = self._entries(axis_cov.reshape(len(x), -1))
        self.t[rows] = np.nan
        self.taken[rows] = True

    def forget(self, rows: np.ndarray) -> None:
        """Rows changed behind the display's back: all of them read again at the next
        frame."""
        rows = rows[rows < len(self.t)]
        self.t[rows] = np.nan
        self.taken[rows] = False

    def _entries(self, axis_cov: np.ndarray) -> np.ndarray:
        """(k, order * order) axis sums -> the distinct entries (n_entries, k) as kept."""
        a = axis_cov[:, self.entries].T
        a[1] *= 2.0  # 2 A01 and (order 3) A22 / 4 as the variance's Horner form takes them
        if self.order == 3:  # (scalings by powers of two: exact)
            a[5] *= 0.25
        return a

    def refresh(self, arrays: TrackArrays, cols: Columns, rows: np.ndarray,
                index: slice | np.ndarray) -> None:
        """Read again the live rows whose time differs from the store's: their time and
        status; their state and axis sums too unless `take` gave them (a row changed
        behind the display's back, or never read)."""
        self.grow(arrays.capacity)
        stale = np.flatnonzero(self.t[index] != arrays.t[index])
        if not len(stale):
            return
        r = stale + index.start if isinstance(index, slice) else rows[stale]
        unseen = r[~self.taken[r]]
        self.taken[r] = False
        if len(unseen):
            self.x[:, unseen] = arrays.x[unseen].T
            o = self.order
            self.a[:, unseen] = self._entries(cols.axis_cov.reshape(-1, o * o)[unseen])
        t, updates = arrays.t[r], arrays.updates[r]
        # as status.status_codes: coasting once the age exceeds coast_after x interval
        interval = np.where(updates > 1, (t - arrays.t_first[r])
                            / np.maximum(updates - 1, 1), np.inf)
        self.limit[r] = self.coast_after * interval
        self.base[r] = updates >= self.order
        self.t[r] = t

    def span(self, rows: np.ndarray) -> slice | np.ndarray:
        """`scratch.span` of the live rows, kept while they are the same array."""
        if rows is not self.rows:
            from ..estimation.scratch import span
            self.rows, self.index = rows, span(rows)
        return self.index

    def draw(self, arrays: TrackArrays, cols: Columns, t: float, q: float
             ) -> tuple[np.ndarray, ...]:
        """pos, vel (N, 3), sigma, age (N,) and status codes (N,) uint8 of the live rows
        at instant t (labelled tracks: the status of tracks of unlabelled scans is left
        to the caller)."""
        rows = arrays.live()[0]
        index = self.span(rows)
        self.refresh(arrays, cols, rows, index)
        m = len(rows)
        width = 3
        make = np.empty if self.dim == width else np.zeros
        pos, vel = make((m, width)), make((m, width))
        sigma, age, codes = np.empty(m), np.empty(m), np.empty(m, np.uint8)
        every = np.ascontiguousarray(rows, dtype=np.int64)  # gaps or not: the live rows

        def part(lo: int, hi: int) -> None:  # each row drawn alone: any split, same bits
            for a in range(lo, hi, CHUNK):
                b = min(hi, a + CHUNK)
                self._chunk(every[a:b], t, q, pos[a:b], vel[a:b], sigma[a:b], age[a:b],
                            codes[a:b])

        blocks.over_rows(m, 1, part)  # the compiled draw releases the GIL
        return pos, vel, sigma, age, codes

    def _chunk(self, rows: np.ndarray, t: float, q: float, pos: np.ndarray,
               vel: np.ndarray, sigma: np.ndarray, age: np.ndarray, codes: np.ndarray
               ) -> None:
        """The store rows `rows` drawn at t into the outputs (`frame_kernel.draw` once
        compiled, `draw_plain` until then: the same bits)."""
        # dim q^2 / ((o - 1)!^2 (2 o - 1)), times |dt|^(2 o): as `predicted_at`
        noise = self.dim * q * q / (20.0 if self.order == 3 else 3.0)
        if jit.ready():
            from .frame_kernel import draw
        else:
            draw = draw_plain
        draw(self.x, self.t, self.a, self.base, self.limit, rows, t, noise, self.dim,
             self.order, pos, vel, sigma, age, codes)


def draw_plain(x: np.ndarray, tt: np.ndarray, a: np.ndarray, base: np.ndarray,
               limit: np.ndarray, rows: np.ndarray, t: float, noise: float, d: int, o: int,
               pos: np.ndarray, vel: np.ndarray, sigma: np.ndarray, age: np.ndarray,
               codes: np.ndarray) -> None:
    """`frame_kernel.draw` in NumPy, row-wise operations in the same order (the same
    bits): it serves until the compiled draw is loaded (`estimation.jit`)."""
    dt = t - tt[rows]
    if o == 3:  # pos = x0 + dt (v + a dt / 2), vel = v + dt a
        h = dt * 0.5
        for k in range(d):
            pos[:, k] = (x[2 * d + k, rows] * h + x[d + k, rows]) * dt + x[k, rows]
            vel[:, k] = x[2 * d + k, rows] * dt + x[d + k, rows]
        w = ((((a[5, rows] * dt + a[4, rows]) * dt + a[3, rows] + a[2, rows]) * dt
              + a[1, rows]) * dt + a[0, rows])
        g = dt * dt
        w += g * g * g * noise
    else:
        for k in range(d):
            pos[:, k] = x[d + k, rows] * dt + x[k, rows]
            vel[:, k] = x[d + k, rows]
        w = (a[2, rows] * dt + a[1, rows]) * dt + a[0, rows]
        g = dt * dt
        w += g * g * noise
    np.sqrt(np.where(w < 0.0, 0.0, w), out=sigma)
    np.copyto(age, np.where(dt < 0.0, 0.0, dt))
    np.copyto(codes, np.where(age > limit[rows], COASTING, base[rows]))


def warm() -> None:
    """Compile the frame's draw (or load it from the cache): `jit.prepare`'s child."""
    from .frame_kernel import draw

    for o, d in ((3, 3), (2, 2)):
        n = o * d
        draw(np.zeros((n, 1)), np.zeros(1), np.zeros((6, 1)), np.zeros(1, np.uint8),
             np.ones(1), np.zeros(1, np.int64), 0.5, 1.0, d, o, np.zeros((1, 3)),
             np.zeros((1, 3)), np.empty(1), np.empty(1), np.empty(1, np.uint8))
