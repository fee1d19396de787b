"""What the display shows between updates: prediction, blended correction, or smoothing.

Pure NumPy over rows of the track store, with the display's own per-row columns
(`DisplayState`: blend offsets and the previous filtered state, kept beside the store).
`predicted` dead-reckons the filtered state to the display instant. `blended` keeps the
drawn position continuous when a correction lands, absorbing it at a limited speed
and/or over a set period. `smoothed` serves a lagged display: the fixed-interval
(Rauch-Tung-Striebel) smoother between the two filtered states that bracket the instant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .. import defaults
from ..estimation import kalman, models
from ..estimation.batch import einsum_as_is
from ..estimation.scratch import span
from ..wire import SHOWN, STATUSES, TIME_TOL
from .frame import FrameColumns
from .status import status_codes
from .store import Column, Columns, TrackArrays, TrackStore


def predicted(x: np.ndarray, t_state: np.ndarray, axis_cov: np.ndarray, t: np.ndarray | float,
              q: float, order: int, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives (N, order, dim) of states x (N, n) filtered at t_state predicted to t,
    and the variance (N,) summed over the position axes (trace of the predicted position
    covariance), from the covariances' axis sums `axis_cov` (N, order, order)."""
    d, o = dim, order
    dt = t - t_state
    phi = models.axis_transition(dt, o)  # (N, o, o)
    xs = phi @ x.reshape(-1, o, d)  # matmul: BLAS-backed, quicker than einsum here
    c0 = phi[:, 0, :]
    var = d * q * q * models.noise_terms(dt, o)[0, 0]  # + c0' axis_cov c0 term by term:
    # small-axis reductions are slow
    for a in range(o):
        for b in range(o):
            var = var + c0[:, a] * c0[:, b] * axis_cov[:, a, b]
    return xs, var


def predicted_at(x: np.ndarray, t_state: np.ndarray, axis_cov: np.ndarray, t: float,
                 q: float, order: int, dim: int, width: int = 3
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`predicted` to one instant t, for the frames: position and velocity (N, width),
    zero beyond `dim`, and the position variance (N,), one axis at a time by Horner's rule
    on columns of N numbers (no (N, o, o) temporaries, no loops over 3 numbers):
    pos = x0 + dt (v + dt a / 2), vel = v + dt a, and c0' A c0 with c0 = (1, dt, dt^2 / 2)
    as A00 + dt (2 A01 + dt (A11 + A02 + dt (A12 + dt A22 / 4))) (A = axis_cov,
    symmetric), plus dim q^2 c00, c00 = |dt|^(2 order) / ((order - 1)!^2 (2 order - 1))
    (`models.noise_terms`). Equal to `predicted` up to
    rounding (tests/test_display.py)."""
    n = len(x)
    pos, vel, var = np.zeros((n, width)), np.zeros((n, width)), np.empty(n)
    for lo in range(0, n, FRAME_CHUNK):  # rows a chunk at a time: each column read
        hi = min(n, lo + FRAME_CHUNK)  # stays in the cache (measured 4 x at 100,000)
        _predicted_rows(x[lo:hi], t_state[lo:hi], axis_cov[lo:hi], t, q, order, dim,
                        pos[lo:hi], vel[lo:hi], var[lo:hi])
    return pos, vel, var


FRAME_CHUNK = 4096  # rows per pass of `predicted_at`


def _predicted_rows(x: np.ndarray, t_state: np.ndarray, axis_cov: np.ndarray, t: float,
                    q: float, order: int, dim: int, pos: np.ndarray, vel: np.ndarray,
                    out: np.ndarray) -> None:
    d, o, n = dim, order, len(x)
    dt = t - t_state
    half = 0.5 * dt if o == 3 else None
    for k in range(d):
        p, v = pos[:, k], vel[:, k]
        if o == 3:
            acc = x[:, 2 * d + k]
            np.multiply(acc, half, out=p)
            p += x[:, d + k]
            np.multiply(acc, dt, out=v)
            v += x[:, d + k]
        else:
            np.copyto(p, x[:, d + k])
            np.copyto(v, p)
        p *= dt
        p += x[:, k]
    a = axis_cov.reshape(n, o * o)
    if o == 3:
        var = a[:, 8] * (0.25 * dt)
        var += a[:, 5]
        var *= dt
        var += a[:, 4]
        var += a[:, 2]
        var *= dt
    else:
        var = a[:, 3] * dt
    var += 2.0 * a[:, 1]
    var *= dt
    var += a[:, 0]
    c00 = np.abs(dt) ** (2 * o)
    c00 *= d * q * q / (math.factorial(o - 1) ** 2 * (2 * o - 1))
    var += c00
    out[:] = var


def axis_traces(p: np.ndarray, order: int, dim: int) -> np.ndarray:
    """(N, order, order): the covariances summed over the spatial axes, block by block
    (derivative i with derivative j); the position variance of a prediction follows from
    them without the full matrix."""
    return einsum_as_is("naibi->nab", p.reshape(-1, order, dim, order, dim))


def frame_before(t: np.ndarray, rate: float) -> np.ndarray:
    """The last display instant n / rate strictly before t (same tolerance as the clock)."""
    return (np.ceil((np.asarray(t, dtype=float) - TIME_TOL) * rate) - 1.0) / rate


def blend_period(offset: np.ndarray, period: float, speed: float) -> np.ndarray:
    """How long each row takes to absorb its correction offset (N, dim): |offset| / speed
    when a speed is set (slew-rate limit: the drawn point never moves faster than `speed`
    relative to the estimate, so small corrections vanish within a frame or two and only
    large ones take long), at most `period` when that is set too; `period` alone: every
    correction over the same period. No offset, no period."""
    size = np.linalg.norm(offset, axis=-1)
    if speed <= 0:
        return np.where(size > 0, float(period), 0.0)
    dur = size / speed
    return np.minimum(dur, period) if period > 0 else dur


def blended(cols: Columns, rows: np.ndarray, t: np.ndarray | float, xs: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position drawn at t while a correction is absorbed: the new estimate's prediction xs
    plus the offset (what was drawn at blend_start minus the new estimate then)
    decaying linearly to zero over the row's blend_period (`blend_period`; 0 for a new
    track, and for a correction that lands on a tentative track). Returns pos, vel
    (N, dim) and a mask of rows still blending.

    blend_start is the last display instant before the correction, so the frame at the
    correction instant already takes the first step, and every frame moves at most
    |offset| / (blend_period x rate) beyond the estimate's own motion. With a speed
    limit that step is the same for every correction (speed / rate), so the jump bound
    costs only the largest corrections time; a fixed period holds small corrections as
    long as large ones. Linear decay is the fastest schedule that keeps each frame's
    step under the bound. This is rate-limited convergence to the estimate, not
    projective velocity blending (Murphy, "Believable Dead Reckoning for Networked
    Games", Game Engine Gems 2, 2011): the new velocity is taken at once, so the old
    trajectory's velocity error stops counting straight away (docs/accuracy.md)."""
    tau = np.broadcast_to(np.asarray(t - cols.blend_start[rows], dtype=float), rows.shape)
    period = cols.blend_period[rows]
    s = np.clip(np.divide(tau, period, out=np.ones_like(tau), where=period > 0), 0.0, 1.0)
    return xs[:, 0] + cols.offset[rows] * (1.0 - s)[:, None], xs[:, 1], s < 1.0


def smoothed(arrays: TrackArrays, cols: Columns, rows: np.ndarray, t: float, q: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RTS smoothing of the instant t between the previous filtered state (prev_x, prev_p
    at prev_t) and the current one (x at t_k): x_s = x_t + C (x_k - x_k^-), C = P_t F' (P_k^-)^-1.
    Returns pos, vel (N, dim) and the mask of rows bracketed by two updates."""
    d, o = arrays.dim, arrays.order
    ok = (arrays.updates[rows] > 1) & (cols.prev_t[rows] <= t) & (t < arrays.t[rows])
    pos = np.full((len(rows), d), np.nan)
    vel = pos.copy()
    r = rows[ok]
    if len(r):
        dt1, dt2 = t - cols.prev_t[r], arrays.t[r] - t
        xt, pt = models.predict(cols.prev_x[r], cols.prev_p[r], dt1, o, d, q)
        f2 = models.transition(dt2, o, d)
        xk = np.einsum("nij,nj->ni", f2, xt)
        pk = f2 @ pt @ f2.transpose(0, 2, 1) + models.process_noise(dt2, o, d, q)
        pk = kalman.symmetrise(pk) + kalman.S_FLOOR * np.eye(arrays.n)
        gain = kalman.solve(pk, (pt @ f2.transpose(0, 2, 1)).transpose(0, 2, 1))
        xs = xt + np.einsum("nji,nj->ni", gain, arrays.x[r] - xk)
        pos[ok], vel[ok] = xs[:, :d], xs[:, d:2 * d]
    return pos, vel, ok & np.isfinite(pos).all(1)


@dataclass(frozen=True)
class DisplayConfig:
    rate: float = defaults.RATE  # Hz: display instants (blending starts at the last one)
    blend: float = defaults.BLEND  # s: absorb a correction over this period (at most)
    blend_speed: float = defaults.BLEND_SPEED  # m/s: absorb a correction at this speed
    lag: float = defaults.LAG  # s: display instants lag the clock; smoothed when bracketed
    coast_after: float = defaults.COAST_AFTER  # status: see `status.status_codes`

    @property
    def blending(self) -> bool:
        return self.blend > 0 or self.blend_speed > 0


@dataclass
class Snapshot:
    """All tracks as drawn at one instant, ready for the display keys."""

    t: float
    ids: list[str]
    pos: np.ndarray  # (N, 3)
    vel: np.ndarray  # (N, 3)
    sigma: np.ndarray  # (N,)
    age: np.ndarray  # (N,)
    status: list[str]
    shown: list[str]  # per track: "prediction", "blend" or "smoothed"
    codes: np.ndarray  # (N,) uint8: each status as an index into wire.STATUSES (frame)
    kinds: np.ndarray | None = None  # (N,) what is shown, as an index into wire.SHOWN

    def select(self, rows: np.ndarray) -> Snapshot:
        """The tracks at `rows` (indices) only."""
        pick = rows.tolist()
        return Snapshot(self.t, [self.ids[i] for i in pick], self.pos[rows], self.vel[rows],
                        self.sigma[rows], self.age[rows],
                        [self.status[i] for i in pick] if self.status else [],
                        [self.shown[i] for i in pick] if self.shown else [], self.codes[rows],
                        None if self.kinds is None else self.kinds[rows])

    def detailed(self) -> Snapshot:
        """This snapshot with its status and shown strings (made from the codes only now,
        for the rows that need them: the display/ keys)."""
        if self.status or not self.ids or self.kinds is None:
            return self
        return replace(self, status=[STATUSES[k] for k in self.codes.tolist()],
                       shown=[SHOWN[k] for k in self.kinds.tolist()])


# the display's columns beside each layout of the store
# the display state's per-row columns in the store (not saved: `initiate` makes them
# again from a restored track's state): the blend offset, its start and period, the
# previous filtered state (for smoothing) and the covariance's axis sums (the predicted
# sigma)
DISPLAY_COLUMNS = {name: Column(code, saved=False) for name, code in (
    ("offset", "d"), ("blend_start", ""), ("blend_period", ""), ("prev_x", "n"),
    ("prev_p", "nn"), ("prev_t", ""), ("axis_cov", "oo"))}


class DisplayState:
    """What the display draws of every track: the filtered state predicted to the display
    instant, with corrections blended in and lagged instants smoothed (`DisplayConfig`).
    Keeps its per-row fields in the store's layouts (`DISPLAY_COLUMNS`)."""

    def __init__(self, config: DisplayConfig, q: float) -> None:
        self.config, self.q = config, q
        self.frames: dict[int, FrameColumns] = {}  # the frames' inputs (`frame`)
        self._ids_cache: tuple[tuple, list[str], list] | None = None

    def columns(self, arrays: TrackArrays) -> Columns:
        """The display's columns of one layout: the layout's own (`DISPLAY_COLUMNS`)."""
        return arrays

    def initiate(self, arrays: TrackArrays, rows: np.ndarray, x: np.ndarray | None = None,
                 p: np.ndarray | None = None) -> None:
        """New tracks: nothing to blend, their first state as the previous one (x, P:
        their states and covariances, if the caller has them)."""
        cols = self.columns(arrays)
        if x is None or p is None:
            x, p = arrays.x[rows], arrays.p[rows]
        if self.config.blending:  # what only a blending display reads
            cols.offset[rows], cols.blend_period[rows] = 0.0, 0.0
            cols.blend_start[rows] = arrays.t[rows]
        cols.prev_t[rows] = arrays.t[rows]
        if self.config.lag > 0:  # the previous state is read only by the smoothing
            cols.prev_x[rows], cols.prev_p[rows] = x, p
        cols.axis_cov[rows] = axis_cov = axis_traces(p, arrays.order, arrays.dim)
        self._take(arrays, rows, x, axis_cov)

    def update(self, arrays: TrackArrays, rows: np.ndarray, t: np.ndarray, x: np.ndarray,
               p: np.ndarray) -> None:
        """Rows are about to take the filtered states x, P at times t (the store still
        holds the previous ones): keep those for smoothing and, when blending, the gap
        between what was drawn at the last display instant before t and where the new
        estimate puts the track then."""
        c, cols = self.config, self.columns(arrays)
        o, d = arrays.order, arrays.dim
        axis_cov = axis_traces(p, o, d)
        self._take(arrays, rows, x, axis_cov)
        if c.blending:  # anchor the blend at the last frame drawn before the correction
            before = frame_before(t, c.rate)
            drawn = self._drawn(arrays, cols, rows, before)[0]
            confirmed = arrays.updates[rows] >= o  # tentative tracks snap
            new = predicted(x, t, axis_cov, before, self.q, o, d)[0][:, 0]
            off = drawn - new
            keep = np.isfinite(off).all(1) & confirmed
            cols.offset[rows] = np.where(keep[:, None], off, 0.0)
            cols.blend_start[rows] = before
            cols.blend_period[rows] = blend_period(cols.offset[rows], c.blend, c.blend_speed)
        if c.lag > 0:  # the previous state is read only by the smoothing of a lagged display
            cols.prev_x[rows], cols.prev_p[rows] = arrays.x[rows], arrays.p[rows]
        cols.prev_t[rows] = arrays.t[rows]
        cols.axis_cov[rows] = axis_cov

    def forget(self, arrays: TrackArrays, rows: np.ndarray) -> None:
        """Rows whose columns were put back (a branch of the second look): the frames
        read them again from the store."""
        frame = self.frames.get(arrays.dim)
        if frame is not None:
            frame.forget(rows)

    def _take(self, arrays: TrackArrays, rows: np.ndarray, x: np.ndarray,
              axis_cov: np.ndarray) -> None:
        """Rows about to take states x with these axis sums: the frames keep them."""
        frame = self.frames.get(arrays.dim)
        if frame is not None:
            frame.grow(arrays.capacity)
            frame.take(rows, x, axis_cov)

    def _frame(self, arrays: TrackArrays, t: float) -> tuple[np.ndarray, ...]:
        """A frame of one layout by `frame.FrameColumns` (plain prediction): pos, vel,
        sigma, age, status codes and kinds of the live rows."""
        frame = self.frames.get(arrays.dim)
        if frame is None:
            frame = self.frames[arrays.dim] = FrameColumns(arrays, self.config.coast_after)
        pos, vel, sigma, age, codes = frame.draw(arrays, self.columns(arrays), t, self.q)
        if arrays.plot[frame.index].any():  # tracks of unlabelled scans: their own status
            codes = status_codes(arrays, frame.index, age, self.config.coast_after)
            codes = codes.astype(np.uint8)
        return pos, vel, sigma, age, codes, np.zeros(len(codes), np.uint8)

    def _drawn(self, arrays: TrackArrays, cols: Columns, rows: np.ndarray,
               t: np.ndarray | float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, position variance and kind (index into SHOWN) of what the
        display shows."""
        c = self.config
        shown = np.zeros(len(rows), dtype=np.int8)
        if np.ndim(t) == 0 and not c.blending:  # a frame: the fast form
            index = span(rows)
            pos, vel, var = predicted_at(arrays.x[index], arrays.t[index],
                                         cols.axis_cov[index], float(t), self.q,  # type: ignore[arg-type]
                                         arrays.order, arrays.dim)
            if c.lag > 0:
                spos, svel, mask = smoothed(arrays, cols, rows, float(t), self.q)  # type: ignore[arg-type]
                pos, vel = np.where(mask[:, None], spos, pos), np.where(mask[:, None], svel, vel)
                shown[mask] = 2
            return pos, vel, var, shown
        xs, var = predicted(arrays.x[rows], arrays.t[rows], cols.axis_cov[rows], t, self.q,
                            arrays.order, arrays.dim)
        pos, vel = xs[:, 0], xs[:, 1]
        if c.blending:
            bpos, bvel, mask = blended(cols, rows, t, xs)
            pos, vel = np.where(mask[:, None], bpos, pos), np.where(mask[:, None], bvel, vel)
            shown[mask] = 1
        if c.lag > 0 and np.ndim(t) == 0:
            spos, svel, mask = smoothed(arrays, cols, rows, float(t), self.q)
            pos, vel = np.where(mask[:, None], spos, pos), np.where(mask[:, None], svel, vel)
            shown[mask] = 2
        return pos, vel, var, shown

    def snapshot(self, store: TrackStore, t: float, detail: bool = True) -> Snapshot:
        """Every track as the display shows it at instant t (no change to any state):
        position, velocity, sigma = sqrt(trace of the predicted position covariance).
        `detail`: also each track's status and what is shown as strings (the display/
        keys); the status codes (the frame's `status` bin) are always there."""
        id_parts: list[list[str]] = []
        parts: list[tuple[np.ndarray, ...]] = []
        status: list[str] = []
        shown: list[str] = []
        c = self.config
        for arrays in store.layouts.values():
            rows, layout_ids = arrays.live()
            if not len(rows):
                continue
            if not c.blending and c.lag <= 0:  # plain prediction: the frames' fast form
                part = self._frame(arrays, float(t))
            else:
                part = self._drawn_part(arrays, rows, t)
            codes, kinds = part[4], part[5]
            if detail:
                status += [STATUSES[k] for k in codes.tolist()]
                shown += [SHOWN[k] for k in kinds.tolist()]
            id_parts.append(layout_ids)
            parts.append(part)
        if not parts:
            e = np.zeros((0, 3))
            return Snapshot(t, [], e, e.copy(), np.zeros(0), np.zeros(0), [], [],
                            np.zeros(0, np.uint8), np.zeros(0, np.uint8))
        if len(parts) == 1:  # one layout (the usual case): no copies
            pos, vel, sig, age, codes, kinds = parts[0]
        else:
            pos, vel, sig, age, codes, kinds = (np.concatenate(p)
                                                for p in zip(*parts, strict=True))
        return Snapshot(t, self._joined(id_parts), pos, vel, sig, age, status, shown, codes,
                        kinds)

    def _drawn_part(self, arrays: TrackArrays, rows: np.ndarray, t: float
                    ) -> tuple[np.ndarray, ...]:
        """`_drawn` of one layout's live rows at t as `_frame` has them: pos, vel (N, 3),
        sigma, age, status codes and kinds (uint8)."""
        d = arrays.dim
        p, v, var, kinds = self._drawn(arrays, self.columns(arrays), rows, t)
        if p.shape[1] == 3:
            pos, vel = p, v
        else:
            pos, vel = np.zeros((len(rows), 3)), np.zeros((len(rows), 3))
            pos[:, :d], vel[:, :d] = p, v
        index = span(rows)
        age = np.maximum(t - arrays.t[index], 0.0)
        codes = status_codes(arrays, index, age, self.config.coast_after)
        return (pos, vel, np.sqrt(np.maximum(var, 0.0)), age, codes.astype(np.uint8),
                np.asarray(kinds, dtype=np.uint8))

    def _joined(self, parts: list[list[str]]) -> list[str]:
        """The layouts' live ids in one list; the same list object while no track comes
        or goes (so the adapter can keep what it derived from it)."""
        key = tuple(id(p) for p in parts)
        if self._ids_cache is None or self._ids_cache[0] != key:
            self._ids_cache = (key, [i for p in parts for i in p], parts)
        return self._ids_cache[1]
