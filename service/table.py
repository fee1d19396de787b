"""The track table: every track's state and covariance in stacked arrays.

Tracks with the same state layout (dimension 2 or 3, model order) live in one `Bank`;
predicting all of them to a display instant, and updating a batch of them, are single
vectorised operations. Names follow the tracking vocabulary: initiate, predict,
update, confirm, coast, delete.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import convert, display, filters
from .validate import Measurement

TIME_TOL = 1e-6  # s: measurements this close to the track time count as simultaneous
STATUS = ("tentative", "confirmed", "coasting")
SHOWN = ("prediction", "blend", "smoothed")


@dataclass
class TableConfig:
    order: int = 2  # 2: nearly-constant velocity, 3: nearly-constant acceleration
    update: str = "cmkf"  # polar measurements: "cmkf" (converted) or "ekf" (linearised)
    filter: Any = None  # a filters.IMM or filters.VDF; None: one model of `order`
    q: float = 1.0  # process noise std: m/s^2 (CV) or m/s^3 (CA), per axis
    init_speed: float = 1000.0  # prior std of velocity at initiation, m/s
    init_accel: float = 10.0  # prior std of acceleration at initiation (CA), m/s^2
    blend: float = 0.0  # s: absorb a correction over this period (at most, with a speed)
    blend_speed: float = 0.0  # m/s: absorb a correction at this speed (0: no speed limit)
    rate: float = 30.0  # Hz: display rate (blending starts from the last frame drawn)
    lag: float = 0.0  # s: display instants lag the clock; shown smoothed when bracketed
    coast_after: float = 2.5  # coasting when age > coast_after x the track's scan interval
    delete_after: float = 30.0  # s of simulation time without a measurement


@dataclass
class Snapshot:
    """All tracks predicted to one instant, ready for the display keys."""

    t: float
    ids: list[str]
    pos: np.ndarray  # (N, 3)
    vel: np.ndarray  # (N, 3)
    sigma: np.ndarray  # (N,)
    age: np.ndarray  # (N,)
    status: list[str]
    shown: list[str]  # per track: "prediction", "blend" or "smoothed"


@dataclass
class States:
    """Filtered states of tracks of one bank, as columns: the `tracks/<id>` bodies."""

    ids: list[str]
    t: np.ndarray  # (N,)
    pos: np.ndarray  # (N, 3), zero-padded for 2-D tracks
    vel: np.ndarray  # (N, 3)
    x: np.ndarray  # (N, n)
    p: np.ndarray  # (N, n * n), row-major
    models: list  # per track: the filter's model label (str, or IMM mode probabilities)
    nis: np.ndarray  # (N,)
    updates: np.ndarray  # (N,) int

    def body(self, i: int) -> dict:
        return {"t": float(self.t[i]), "id": self.ids[i], "pos": self.pos[i].tolist(),
                "vel": self.vel[i].tolist(), "x": self.x[i].tolist(), "P": self.p[i].tolist(),
                "model": self.models[i], "nis": float(self.nis[i]),
                "updates": int(self.updates[i])}


@dataclass
class Outcome:
    meas: Measurement
    reason: str | None  # None: accepted
    nis: float = float("nan")
    states: States | None = None  # accepted: the tracks updated with it, this one among them


class Bank:
    """Tracks of one layout: states x (cap, n), covariances P (cap, n, n), bookkeeping,
    and the per-row arrays a filter asks for (`extra`: name -> (shape code, modes))."""

    def __init__(self, dim: int, order: int, extra: dict[str, tuple] | None = None,
                 capacity: int = 64) -> None:
        self.dim, self.order, self.n = dim, order, dim * order
        n = self.n
        codes = {"": (), "n": (n,), "nn": (n, n), "d": (dim,), "dd": (dim, dim)}
        self.shapes: dict[str, tuple[int, ...]] = {
            "x": (n,), "p": (n, n), "t": (), "t_first": (), "nis": (), "updates": (),
            "alive": (),
            # display blending: drawn minus estimate at instant bt, absorbed over bd
            "bo": (dim,), "bt": (), "bd": (),
            # the previous filtered state (display smoothing)
            "px": (n,), "pp": (n, n), "pt": (),
            # P summed over the axes per derivative block (display prediction)
            "ptr": (order, order)}
        for name, (code, modes) in (extra or {}).items():
            self.shapes[name] = ((modes,) if modes else ()) + codes[code]
        self.ids: list[str | None] = []
        self.free: list[int] = []
        self._live: tuple[np.ndarray, list[str]] | None = None
        for name, shape in self.shapes.items():
            setattr(self, name, np.zeros((0, *shape), dtype=self._dtype(name)))
        self._grow(capacity)

    @staticmethod
    def _dtype(name: str) -> type:
        return bool if name == "alive" else np.int64 if name == "updates" else float

    def _grow(self, capacity: int) -> None:
        old = len(self.ids)
        for name, shape in self.shapes.items():
            a = getattr(self, name)
            grown = np.zeros((capacity, *shape), dtype=a.dtype)
            grown[:old] = a
            setattr(self, name, grown)
        self.ids.extend([None] * (capacity - old))
        self.free.extend(range(capacity - 1, old - 1, -1))

    def add(self, track_id: str) -> int:
        if not self.free:
            self._grow(2 * len(self.ids))
        row = self.free.pop()
        self.ids[row] = track_id
        self.alive[row] = True
        self._live = None
        return row

    def remove(self, row: int) -> None:
        self.ids[row] = None
        self.alive[row] = False
        self.free.append(row)
        self._live = None

    def live(self) -> tuple[np.ndarray, list[str]]:
        """Rows of the live tracks and their ids, cached until a track comes or goes
        (every display frame asks)."""
        if self._live is None:
            rows = np.flatnonzero(self.alive)
            ids = self.ids
            self._live = (rows, [ids[i] for i in rows.tolist()])  # type: ignore[misc]
        return self._live

    def rows(self) -> np.ndarray:
        return self.live()[0]


def measurement_arrays(meas: Sequence[Measurement] | convert.MeasurementBatch, dim: int,
                       pred: np.ndarray | None, pred_cov: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Converted measurements z (N, dim) and covariances R (N, dim, dim) in the common
    frame. Polar ones use the UCM, with R averaged over the predicted position
    N(pred, pred_cov) when given, else evaluated at the converted point (initiation).
    `meas`: the records, or their columns (`convert.MeasurementBatch`)."""
    if not isinstance(meas, convert.MeasurementBatch):
        meas = convert.MeasurementBatch.of(meas, dim)
    return convert.cmkf_arrays(meas, pred, pred_cov)


def ekf_arrays(meas: Sequence[Measurement] | convert.MeasurementBatch, dim: int,
               pred: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """EKF baseline: polar measurements kept polar (z, R = diag of the noise variances),
    with the Jacobian h and predicted measurement hx at the predicted position; Cartesian
    ones as in the CMKF (h = I, hx = position)."""
    batch = meas if isinstance(meas, convert.MeasurementBatch) else \
        convert.MeasurementBatch.of(meas, dim)
    z, r = measurement_arrays(batch, dim, None)
    h = np.broadcast_to(np.eye(dim), (len(batch), dim, dim)).copy()
    hx = pred.copy()
    polar = batch.polar
    if polar.any():
        origin, sig = batch.origin[polar, :dim], batch.sigmas[polar]
        hx[polar], h[polar], z[polar] = convert.polar_linearised(
            pred[polar] - origin, batch.values[polar])
        r[polar] = sig[:, :, None] ** 2 * np.eye(dim)
    return z, r, h, hx


class TrackTable:
    """All tracks, keyed by target id, one CMKF state each."""

    def __init__(self, config: TableConfig | None = None) -> None:
        self.config = c = config or TableConfig()
        self.filter = c.filter or filters.Single({2: "cv", 3: "ca"}[c.order], c.q, c.order)
        c.order = self.filter.order
        self.banks: dict[int, Bank] = {}
        self.where: dict[str, tuple[Bank, int]] = {}
        self._ids_cache: tuple[tuple, list[str], list] | None = None

    def __len__(self) -> int:
        return len(self.where)

    def bank(self, dim: int) -> Bank:
        if dim not in self.banks:
            self.banks[dim] = Bank(dim, self.config.order, self.filter.fields)
        return self.banks[dim]

    # ------------------------------------------------------------ initiate / update
    def apply(self, meas: Sequence[Measurement]) -> list[Outcome]:
        """Initiate or update one track per measurement, in order. A target measured
        twice in the batch is updated twice (the batch is split into rounds)."""
        outcomes: list[Outcome | None] = [None] * len(meas)
        pending = list(range(len(meas)))
        while pending:
            seen: set[str] = set()
            now, later = [], []
            for i in pending:
                (later if meas[i].target in seen else now).append(i)
                seen.add(meas[i].target)
            for i, out in zip(now, self._apply_round([meas[i] for i in now]), strict=True):
                outcomes[i] = out
            pending = later
        return outcomes  # type: ignore[return-value]

    def _apply_round(self, meas: list[Measurement]) -> list[Outcome]:
        out = [Outcome(m, None) for m in meas]
        groups: dict[tuple[int, bool], list[int]] = {}
        for i, m in enumerate(meas):
            hit = self.where.get(m.target)
            if hit is None:
                groups.setdefault((m.dim, True), []).append(i)
            elif hit[0].dim != m.dim:
                out[i].reason = f"{m.dim}-D measurement for a {hit[0].dim}-D track"
            elif m.t < hit[0].t[hit[1]] - TIME_TOL:
                out[i].reason = (f"out of sequence: t={m.t:.6f} is before the track's last "
                                 f"update at t={hit[0].t[hit[1]]:.6f}")
            else:
                groups.setdefault((m.dim, False), []).append(i)
        for (dim, new), idx in groups.items():
            sub = [meas[i] for i in idx]
            res = self._initiate(dim, sub) if new else self._update(dim, sub)
            for i, (reason, nis) in zip(idx, res, strict=True):
                out[i].reason, out[i].nis = reason, nis
            good = [i for i, (reason, _) in zip(idx, res, strict=True) if reason is None]
            block = self.states(self.bank(dim), [self.where[meas[i].target][1] for i in good])
            for i in good:
                out[i].states = block
        return out

    def _initiate(self, dim: int, meas: list[Measurement]) -> list[tuple[str | None, float]]:
        """One-point initiation: position from the converted measurement, velocity (and
        acceleration) zero with a wide prior; the second measurement then gives the
        two-point difference in the limit of a diffuse prior (Mallick & La Scala,
        'Comparison of single-point and two-point difference track initiation', 2008)."""
        bank, c = self.bank(dim), self.config
        z, r = measurement_arrays(meas, dim, None)
        finite = np.isfinite(z).all(1) & np.isfinite(r).all((1, 2))
        prior = [c.init_speed**2, c.init_accel**2][: bank.order - 1]
        rows = []
        for m, zi, ri, ok in zip(meas, z, r, finite, strict=True):
            if not ok:
                continue
            row = bank.add(m.target)
            rows.append(row)
            self.where[m.target] = (bank, row)
            bank.x[row] = 0.0
            bank.x[row, :dim] = zi
            bank.p[row] = np.diag(np.repeat([0.0, *prior], dim))
            bank.p[row, :dim, :dim] = ri
            bank.t[row] = bank.t_first[row] = bank.bt[row] = bank.pt[row] = m.t
            bank.bo[row], bank.bd[row] = 0.0, 0.0
            bank.px[row], bank.pp[row] = bank.x[row], bank.p[row]
            bank.updates[row] = 1
            bank.nis[row] = 0.0
        self.filter.initiate(bank, np.array(rows, dtype=int))
        bank.ptr[rows] = display.axis_traces(bank.p[rows], bank.order, dim)
        return [(None, 0.0) if ok else ("conversion gave a non-finite value", np.nan)
                for ok in finite]

    def _update(self, dim: int, meas: list[Measurement]) -> list[tuple[str | None, float]]:
        bank, c = self.bank(dim), self.config
        rows = np.array([self.where[m.target][1] for m in meas], dtype=int)
        t = np.array([m.t for m in meas])

        batch = convert.MeasurementBatch.of(meas, dim)  # the records as columns, once
        if c.update == "ekf":
            def conversion(xp: np.ndarray, pp: np.ndarray) -> tuple:
                return ekf_arrays(batch, dim, xp[:, :dim])
        else:  # (xp, pp) -> z, R; filters.cmkf_step converts its columns directly
            conversion = convert.CMKFConversion(batch)

        xn, pn, nis, ok = self.filter.update(bank, rows, t - bank.t[rows], conversion)
        good = rows[ok]
        blend = c.blend > 0 or c.blend_speed > 0
        if blend:  # anchor the blend at the last frame drawn before the correction
            before = display.frame_before(t[ok], c.rate)
            drawn = self._drawn(bank, good, before)[0]
            confirmed = bank.updates[good] >= bank.order  # tentative tracks snap
        bank.px[good], bank.pp[good], bank.pt[good] = bank.x[good], bank.p[good], bank.t[good]
        bank.x[good], bank.p[good], bank.nis[good] = xn[ok], pn[ok], nis[ok]
        bank.ptr[good] = display.axis_traces(pn[ok], bank.order, dim)
        bank.t[good] = t[ok]
        bank.updates[good] += 1
        if blend:
            off = drawn - display.predicted(bank, good, before, c.q)[0][:, 0]
            keep = np.isfinite(off).all(1) & confirmed
            bank.bo[good] = np.where(keep[:, None], off, 0.0)
            bank.bt[good] = before
            bank.bd[good] = display.blend_period(bank.bo[good], c.blend, c.blend_speed)
        return [(None, float(v)) if k else ("update gave a non-finite state", np.nan)
                for k, v in zip(ok, nis, strict=True)]

    # ------------------------------------------------------------ display
    def _drawn(self, bank: Bank, rows: np.ndarray, t: np.ndarray | float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, position variance and kind (index into SHOWN) of what the
        display shows."""
        c = self.config
        xs, var = display.predicted(bank, rows, t, c.q)
        pos, vel = xs[:, 0], xs[:, 1]
        shown = np.zeros(len(rows), dtype=np.int8)
        if c.blend > 0 or c.blend_speed > 0:
            bpos, bvel, mask = display.blended(bank, rows, t, xs)
            pos, vel = np.where(mask[:, None], bpos, pos), np.where(mask[:, None], bvel, vel)
            shown[mask] = 1
        if c.lag > 0 and np.ndim(t) == 0:
            spos, svel, mask = display.smoothed(bank, rows, float(t), c.q)
            pos, vel = np.where(mask[:, None], spos, pos), np.where(mask[:, None], svel, vel)
            shown[mask] = 2
        return pos, vel, var, shown

    def snapshot(self, t: float, detail: bool = True) -> Snapshot:
        """Every track as the display shows it at instant t (no change to the table):
        position, velocity, sigma = sqrt(trace of the predicted position covariance).
        `detail`: also each track's status and what is shown (the display/ keys; the
        frame does not carry them)."""
        id_parts: list[list[str]] = []
        parts: list[tuple[np.ndarray, ...]] = []
        status: list[str] = []
        shown: list[str] = []
        c = self.config
        for bank in self.banks.values():
            rows, bank_ids = bank.live()
            if not len(rows):
                continue
            d = bank.dim
            p, v, var, kinds = self._drawn(bank, rows, t)
            pos = np.zeros((len(rows), 3))
            vel = np.zeros((len(rows), 3))
            pos[:, :d], vel[:, :d] = p, v
            age = np.maximum(t - bank.t[rows], 0.0)
            if detail:
                updates = bank.updates[rows]
                interval = np.where(updates > 1, (bank.t[rows] - bank.t_first[rows])
                                    / np.maximum(updates - 1, 1), np.inf)
                coasting = age > c.coast_after * interval
                code = np.where(coasting, 2, (updates >= bank.order).astype(np.int8))
                status += [STATUS[k] for k in code.tolist()]
                shown += [SHOWN[k] for k in kinds.tolist()]
            id_parts.append(bank_ids)
            parts.append((pos, vel, np.sqrt(np.maximum(var, 0.0)), age))
        if not parts:
            e = np.zeros((0, 3))
            return Snapshot(t, [], e, e.copy(), np.zeros(0), np.zeros(0), [], [])
        pos, vel, sig, age = (np.concatenate(p) for p in zip(*parts, strict=True))
        return Snapshot(t, self._joined(id_parts), pos, vel, sig, age, status, shown)

    def _joined(self, parts: list[list[str]]) -> list[str]:
        """The banks' live ids in one list; the same list object while no track comes or
        goes (so the display side can keep what it derived from it)."""
        key = tuple(id(p) for p in parts)
        if self._ids_cache is None or self._ids_cache[0] != key:
            self._ids_cache = (key, [i for p in parts for i in p], parts)
        return self._ids_cache[1]

    # ------------------------------------------------------------ queries / delete
    def state(self, track_id: str) -> dict:
        """The filtered state of one track (the `tracks/<id>` message body)."""
        bank, row = self.where[track_id]
        return self.states(bank, [row]).body(0)

    def states(self, bank: Bank, rows: Sequence[int]) -> States:
        """The filtered states of rows of a bank, as columns."""
        r = np.asarray(rows, dtype=int)
        d, n = bank.dim, len(r)
        x = bank.x[r]
        pos, vel = np.zeros((n, 3)), np.zeros((n, 3))
        pos[:, :d], vel[:, :d] = x[:, :d], x[:, d:2 * d]
        ids = bank.ids
        return States([ids[i] for i in r.tolist()], bank.t[r], pos, vel, x,  # type: ignore[misc]
                      bank.p[r].reshape(n, -1), self.filter.labels(bank, r), bank.nis[r],
                      bank.updates[r])

    def stale(self, t: float) -> list[str]:
        """Ids of tracks with no measurement for longer than `delete_after`."""
        out: list[str] = []
        for bank in self.banks.values():
            rows, ids = bank.live()
            old = np.flatnonzero(t - bank.t[rows] > self.config.delete_after)
            out += [ids[i] for i in old.tolist()]
        return out

    def delete(self, ids: Iterable[str]) -> None:
        for track_id in ids:
            bank, row = self.where.pop(track_id)
            bank.remove(row)
