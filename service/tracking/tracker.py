"""The tracker: the loop of the field's textbook over the stacked track store.

Each scan of measurements is associated with the tracks, the associated tracks are
predicted and updated, the others coast, stale tracks are deleted and unassociated
measurements start new tracks (`Tracker.step`). Each step is a component with Stone
Soup's name (associator, updater, deleter, initiator) so that one can be swapped
without touching the rest; the display state follows every change. Labelled
measurements go through the `LabelAssociator`; unlabelled radar scans through the GNN
or JPDA associator (`association`), and their tracks live by M of N (`life`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import defaults
from ..estimation.catalog import FilterSpec
from ..estimation.ekf import EKFConversion
from ..estimation.measurements import MeasurementBatch
from ..estimation.ucm import CMKFConversion
from ..wire import Measurement
from .association import GNNAssociator, JPDAAssociator, SensorModels
from .associator import Hypotheses, LabelAssociator, WeightedUpdate
from .deleter import CompositeDeleter, UpdateTimeDeleter
from .display import DisplayConfig, DisplayState, Snapshot
from .initiator import SinglePointInitiator
from .life import MofNDeleter, update_life
from .store import States, TrackArrays, TrackStore

if TYPE_CHECKING:
    from ..wire.plots import PlotScan


@dataclass(frozen=True)
class TrackerConfig:
    """What a tracker is built from; every default from `service.defaults`."""

    filter: FilterSpec = field(default_factory=FilterSpec)  # the updater, by name
    init_speed: float = defaults.INIT_SPEED  # m/s: prior std of velocity at initiation
    init_accel: float = defaults.INIT_ACCEL  # m/s^2: prior std of acceleration (order 3)
    delete_after: float = defaults.DELETE_AFTER  # s of simulation time without a measurement
    display: DisplayConfig = field(default_factory=DisplayConfig)
    # unlabelled scans (plots/)
    associator: str = defaults.ASSOCIATOR  # "gnn" or "jpda"
    sensors: SensorModels = field(default_factory=SensorModels)
    gate_probability: float = defaults.GATE_PROBABILITY
    max_speed: float = defaults.MAX_SPEED  # m/s: a new track's velocity std is a third
    confirm_m: int = defaults.CONFIRM_M
    confirm_n: int = defaults.CONFIRM_N
    confirm_score: float = defaults.CONFIRM_SCORE
    delete_misses: int = defaults.DELETE_MISSES
    delete_sigma: float = defaults.DELETE_SIGMA


@dataclass(frozen=True)
class EquivalentConversion:
    """A PDA update as one equivalent measurement per track (`association.pda`): called
    with the filter's own prediction it returns z and R~ = R / b + ((1 - b) / b) H P H'."""

    z: np.ndarray
    r: np.ndarray
    mass: np.ndarray

    def __call__(self, xp: np.ndarray, pp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d, b = self.z.shape[1], self.mass[:, None, None]
        return self.z, self.r / b + (1 - b) / b * pp[:, :d, :d]


@dataclass
class Outcome:
    """What became of one measurement."""

    meas: Measurement
    reason: str | None = None  # None: accepted
    nis: float = float("nan")
    states: States | None = None  # accepted: the tracks updated with it, this one among them


class Tracker:
    """All tracks, keyed by target id: one filtered state each, in a `TrackStore`."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = c = config or TrackerConfig()
        self.updater, q, self.conversion = c.filter.build()
        self.associator = LabelAssociator()
        scans = {"gnn": GNNAssociator, "jpda": JPDAAssociator}[c.associator]
        self.scan_associator = scans(q, c.sensors, c.gate_probability)
        self.initiator = SinglePointInitiator(c.init_speed, c.init_accel)
        self.deleter = CompositeDeleter(
            UpdateTimeDeleter(c.delete_after),
            MofNDeleter(c.confirm_m, c.confirm_n, c.delete_misses, c.delete_sigma))
        self.display = DisplayState(c.display, q)
        self.store = TrackStore(self.updater.order, self.updater.fields)
        self.numbers: dict[str, int] = {}  # per sensor: the last track number given

    def __len__(self) -> int:
        return len(self.store)

    def track(self, measurements: Sequence[Measurement]) -> tuple[list[Outcome], list[str]]:
        """Apply a batch of measurements in order, one `step` per scan (the associator
        splits the batch so that a scan holds each target at most once). Returns the
        outcome of every measurement and the ids of the tracks deleted."""
        outcomes = [Outcome(m) for m in measurements]
        deleted: list[str] = []
        for scan in self.associator.scans(measurements):
            deleted += self.step([outcomes[i] for i in scan])
        return outcomes, deleted

    def track_scan(self, scan: PlotScan) -> tuple[list[Outcome], list[str]]:
        """Apply one unlabelled scan (all its detections at one time): one `step` with
        the scan associator (one per dimension when it mixes 2-D and 3-D detections).
        Returns each detection's outcome and the tracks deleted."""
        outcomes = [Outcome(m) for m in scan.detections]
        dims = {m.dim for m in scan.detections}
        if len(dims) < 2:
            return outcomes, self.step(outcomes, scan.t, self.scan_associator)
        deleted: list[str] = []  # 2-D and 3-D detections in one scan: each with its tracks
        for dim in sorted(dims):
            deleted += self.step([o for o in outcomes if o.meas.dim == dim], scan.t,
                                 self.scan_associator)
        return outcomes, deleted

    def step(self, scan: Sequence[Outcome], now: float | None = None,
             associator: Any = None) -> list[str]:
        """One scan at time `now` (default: its newest measurement): associate, predict
        and update, coast, delete, initiate. Fills in each measurement's outcome and
        returns the ids of the tracks deleted."""
        meas = [o.meas for o in scan]
        hypotheses = (associator or self.associator).associate(self.store, meas, now)
        for i, reason in hypotheses.rejected.items():
            scan[i].reason = reason
        for dim, idx in hypotheses.updates.items():
            rows = hypotheses.rows.get(dim)
            self.update(dim, [scan[i] for i in idx],
                        hypotheses.tracks[dim] if rows is None else np.concatenate(rows),
                        hypotheses.batch(meas, dim, idx))
        for weighted in hypotheses.weighted:
            self.update_weighted(weighted, scan, now)
        self.coast(hypotheses)
        if now is None:
            now = max((m.t for m in meas), default=None)
        deleted = self.delete(now) if now is not None else []
        for dim, idx in hypotheses.unassociated.items():
            self.initiate(dim, [scan[i] for i in idx], hypotheses.batch(meas, dim, idx))
        return deleted

    # ------------------------------------------------------------ the steps
    def update(self, dim: int, scan: list[Outcome], tracks: list[str] | np.ndarray,
               batch: MeasurementBatch) -> None:
        """Predict and update `tracks` (of one layout: ids, or their rows) with their
        measurements (`batch`: the same as columns)."""
        store = self.store
        arrays = store.layout(dim)
        rows = tracks if isinstance(tracks, np.ndarray) else \
            np.array([store.where[k][1] for k in tracks], dtype=int)
        good, ok, nis, xn, pn = self._update_rows(arrays, rows, batch)
        if len(good) == len(rows):  # every row updated (the usual case)
            block = self.states(arrays, good, xn, pn)
            for out, v in zip(scan, nis.tolist(), strict=True):
                out.reason, out.nis, out.states = None, v, block
            return
        self._settle(scan, arrays, good, [(None, v) if k else
                                          ("update gave a non-finite state", np.nan)
                                          for k, v in zip(ok.tolist(), nis.tolist(),
                                                          strict=True)], xn, pn)

    def update_rows(self, arrays: TrackArrays, rows: np.ndarray, batch: MeasurementBatch
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predict and update `rows` of `arrays` with `batch` (row i with measurement i):
        the rows updated (those whose result is finite), the mask of them and every NIS."""
        return self._update_rows(arrays, rows, batch)[:3]

    def _update_rows(self, arrays: TrackArrays, rows: np.ndarray, batch: MeasurementBatch
                     ) -> tuple[np.ndarray, ...]:
        """`update_rows`, and the new states and covariances of the rows updated."""
        t = batch.t
        conversion = EKFConversion(batch) if self.conversion == "ekf" else \
            CMKFConversion(batch)  # the filter core converts a CMKF batch in its kernel
        xn, pn, nis, ok = self.updater.update(arrays, rows, t - arrays.t[rows], conversion)
        every = np.count_nonzero(ok) == len(ok)
        good = rows if every else rows[ok]
        if not every:
            xn, pn, nis_ok, t = xn[ok], pn[ok], nis[ok], t[ok]
        else:
            nis_ok = nis
        self.display.update(arrays, good, t, xn, pn)
        arrays.x[good], arrays.p[good], arrays.nis[good] = xn, pn, nis_ok
        arrays.t[good] = t
        arrays.updates[good] += 1
        return good, ok, nis, xn, pn

    def update_weighted(self, w: WeightedUpdate, scan: Sequence[Outcome], t: float) -> None:
        """Update tracks each with the equivalent measurement of its weighted detections
        (JPDA), then add the spread of those detections to their covariances."""
        arrays, rows = w.arrays, w.rows
        times = np.full(len(rows), t)
        xn, pn, nis, ok = self.updater.update(arrays, rows, times - arrays.t[rows],
                                              EquivalentConversion(w.z, w.r, w.mass))
        pn = pn + w.spread
        self.updater.inflate(arrays, rows[ok], w.spread[ok])
        good, xn, pn = rows[ok], xn[ok], pn[ok]
        self.display.update(arrays, good, times[ok], xn, pn)
        arrays.x[good], arrays.p[good], arrays.nis[good] = xn, pn, nis[ok]
        arrays.t[good] = t
        arrays.updates[good] += 1
        block = self.states(arrays, good, xn, pn)
        for out in scan:  # every detection shares the block of the tracks it updated
            if out.states is None:
                out.states = block
                break

    def coast(self, hypotheses: Hypotheses) -> None:
        """Tracks without a detection keep their filtered state, which the display state
        predicts to every instant (labelled ones turn coasting with age); unlabelled ones
        count the scan as a detection or a miss (M of N)."""
        c = self.config
        update_life(hypotheses.seen, c.confirm_m, c.confirm_n, c.confirm_score)

    def delete(self, now: float) -> list[str]:
        """Remove the tracks the deleter picks at time `now`; their ids."""
        return self.remove(self.deleter.delete_tracks(self.store, now))

    def drop_newer(self, t: float) -> list[str]:
        """Remove the tracks updated after time t (a timeline abandoned for an earlier
        one: they would never age out); their ids."""
        ids: list[str] = []
        for arrays in self.store.layouts.values():
            rows, names = arrays.live()
            ids += [names[i] for i in np.flatnonzero(arrays.t[rows] > t + 1e-6).tolist()]
        return self.remove(ids)

    def remove(self, ids: list[str]) -> list[str]:
        self.store.remove(ids)
        self.associator.forget(ids)
        return ids

    def initiate(self, dim: int, scan: list[Outcome], batch: MeasurementBatch) -> None:
        """Start a track from each unassociated measurement of one layout: named by its
        label, or, unlabelled, `<sensor>-<n>` with n counting per sensor from 1 (never
        reused in a run), tentative until confirmed M of N."""
        meas = [o.meas for o in scan]
        unlabelled = bool(meas) and not meas[0].target
        ids = self._new_ids([m.sensor for m in meas]) if unlabelled else \
            [m.target for m in meas]
        speed = self.config.max_speed / 3 if unlabelled else None
        arrays, rows, reasons = self.initiator.initiate(self.store, dim, batch, ids, speed)
        if unlabelled:
            arrays.plot[rows], arrays.hits[rows], arrays.scans[rows] = True, 1, 1
            arrays.confirmed[rows] = self.config.confirm_m <= 1 and \
                self.config.confirm_score <= 0
        self.updater.initiate(arrays, rows)
        x, p = arrays.x[rows], arrays.p[rows]
        self.display.initiate(arrays, rows, x, p)
        self._settle(scan, arrays, rows, [(r, 0.0 if r is None else np.nan) for r in reasons],
                     x, p)

    def _settle(self, scan: list[Outcome], arrays: TrackArrays, good: np.ndarray,
                results: list[tuple[str | None, float]], x: np.ndarray | None = None,
                p: np.ndarray | None = None) -> None:
        """Record each measurement's reason and NIS, and the accepted ones' new states
        (one block of columns for all of them; x, P: their states and covariances, when
        the caller has them as new arrays)."""
        block = self.states(arrays, good, x, p)
        for out, (reason, nis) in zip(scan, results, strict=True):
            out.reason, out.nis = reason, nis
            if reason is None:
                out.states = block

    def _new_ids(self, sensors: list[str]) -> list[str]:
        """Ids `<sensor>-<n>` for new unlabelled tracks of these sensors, n counting per
        sensor from 1."""
        numbers, out = self.numbers, []
        if sensors and sensors.count(sensors[0]) == len(sensors):  # one sensor (a scan)
            s, n0 = sensors[0], numbers.get(sensors[0], 0)
            numbers[s] = n0 + len(sensors)
            return [f"{s}-{n}" for n in range(n0 + 1, n0 + 1 + len(sensors))]
        for sensor in sensors:
            n = numbers[sensor] = numbers.get(sensor, 0) + 1
            out.append(f"{sensor}-{n}")
        return out

    # ------------------------------------------------------------ queries
    def states(self, arrays: TrackArrays, rows: Sequence[int] | np.ndarray,
               x: np.ndarray | None = None, p: np.ndarray | None = None) -> States:
        """The filtered states of rows of one layout, as columns (x, P: those rows'
        states and covariances, new arrays, if the caller has them)."""
        r = np.asarray(rows, dtype=int)
        return self.store.states(arrays, r, self.updater.labels(arrays, r), x, p)

    def state(self, track_id: str) -> dict:
        """The filtered state of one track (the `tracks/<id>` message body)."""
        arrays, row = self.store.where[track_id]
        return self.states(arrays, [row]).body(0)

    def snapshot(self, t: float, detail: bool = True) -> Snapshot:
        """Every track as the display shows it at instant t (`display.DisplayState`)."""
        return self.display.snapshot(self.store, t, detail)
