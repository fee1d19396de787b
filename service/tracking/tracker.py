"""The tracker: the loop of the field's textbook over the stacked track store.

Each scan of measurements is associated with the tracks, the associated tracks are
predicted and updated, the others coast, stale tracks are deleted and unassociated
measurements start new tracks (`Tracker.step`). Each step is a component with Stone
Soup's name (associator, updater, deleter, initiator) so that one can be swapped
without touching the rest; the display state follows every change.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import defaults
from ..estimation.ekf import EKFConversion
from ..estimation.filters import SingleModelFilter
from ..estimation.measurements import MeasurementBatch
from ..estimation.ucm import CMKFConversion
from ..wire import Measurement
from .associator import LabelAssociator
from .deleter import UpdateTimeDeleter
from .display import DisplayConfig, DisplayState
from .initiator import SinglePointInitiator
from .store import States, TrackArrays, TrackStore


@dataclass(frozen=True)
class TrackerConfig:
    """What a tracker is built from; every default from `service.defaults`."""

    order: int = 2  # of the single-model filter: 2 nearly-constant velocity, 3 acceleration
    conversion: str = "cmkf"  # polar measurements: "cmkf" (converted) or "ekf" (linearised)
    filter: Any = None  # an estimation IMM or VDF; None: one model of `order`
    q: float = defaults.Q_CV  # process noise std: m/s^2 (CV) or m/s^3 (CA), per axis
    init_speed: float = defaults.INIT_SPEED  # m/s: prior std of velocity at initiation
    init_accel: float = defaults.INIT_ACCEL  # m/s^2: prior std of acceleration (order 3)
    delete_after: float = defaults.DELETE_AFTER  # s of simulation time without a measurement
    display: DisplayConfig = field(default_factory=DisplayConfig)


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
        kind = {2: "cv", 3: "ca"}.get(c.order, "cv")
        self.updater = c.filter or SingleModelFilter(kind, c.q, c.order)
        self.associator = LabelAssociator()
        self.initiator = SinglePointInitiator(c.init_speed, c.init_accel)
        self.deleter = UpdateTimeDeleter(c.delete_after)
        self.display = DisplayState(c.display, c.q)
        self.store = TrackStore(self.updater.order, self.updater.fields)

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

    def step(self, scan: Sequence[Outcome], now: float | None = None) -> list[str]:
        """One scan at time `now` (default: its newest measurement): associate, predict
        and update, coast, delete, initiate. Fills in each measurement's outcome and
        returns the ids of the tracks deleted."""
        meas = [o.meas for o in scan]
        hypotheses = self.associator.associate(self.store, meas)
        for i, reason in hypotheses.rejected.items():
            scan[i].reason = reason
        for dim, idx in hypotheses.updates.items():
            self.update(dim, [scan[i] for i in idx])
        # coast: tracks without a detection keep their filtered state, which the display
        # state predicts to every instant; their status turns to coasting with age
        if now is None:
            now = max((m.t for m in meas), default=None)
        deleted = self.delete(now) if now is not None else []
        for dim, idx in hypotheses.unassociated.items():
            self.initiate(dim, [scan[i] for i in idx])
        return deleted

    # ------------------------------------------------------------ the steps
    def update(self, dim: int, scan: list[Outcome]) -> None:
        """Predict and update the tracks of measurements associated in one layout."""
        store = self.store
        arrays = store.layout(dim)
        meas = [o.meas for o in scan]
        rows = np.array([store.where[m.target][1] for m in meas], dtype=int)
        t = np.array([m.t for m in meas])
        batch = MeasurementBatch.of(meas, dim)  # the records as columns, once
        conversion = EKFConversion(batch) if self.config.conversion == "ekf" else \
            CMKFConversion(batch)  # the filter core converts a CMKF batch in its kernel
        xn, pn, nis, ok = self.updater.update(arrays, rows, t - arrays.t[rows], conversion)
        good = rows[ok]
        self.display.update(arrays, good, t[ok], xn[ok], pn[ok])
        arrays.x[good], arrays.p[good], arrays.nis[good] = xn[ok], pn[ok], nis[ok]
        arrays.t[good] = t[ok]
        arrays.updates[good] += 1
        self._settle(scan, arrays, good, [(None, float(v)) if k else
                                          ("update gave a non-finite state", np.nan)
                                          for k, v in zip(ok, nis, strict=True)])

    def delete(self, now: float) -> list[str]:
        """Remove the tracks the deleter picks at time `now`; their ids."""
        ids = self.deleter.delete_tracks(self.store, now)
        self.store.remove(ids)
        return ids

    def initiate(self, dim: int, scan: list[Outcome]) -> None:
        """Start a track from each unassociated measurement of one layout."""
        arrays, rows, reasons = self.initiator.initiate(self.store, dim,
                                                        [o.meas for o in scan])
        self.updater.initiate(arrays, rows)
        self.display.initiate(arrays, rows)
        self._settle(scan, arrays, rows, [(r, 0.0 if r is None else np.nan) for r in reasons])

    def _settle(self, scan: list[Outcome], arrays: TrackArrays, good: np.ndarray,
                results: list[tuple[str | None, float]]) -> None:
        """Record each measurement's reason and NIS, and the accepted ones' new states
        (one block of columns for all of them)."""
        block = self.states(arrays, good)
        for out, (reason, nis) in zip(scan, results, strict=True):
            out.reason, out.nis = reason, nis
            if reason is None:
                out.states = block

    # ------------------------------------------------------------ queries
    def states(self, arrays: TrackArrays, rows: Sequence[int] | np.ndarray) -> States:
        """The filtered states of rows of one layout, as columns."""
        r = np.asarray(rows, dtype=int)
        return self.store.states(arrays, r, self.updater.labels(arrays, r))

    def state(self, track_id: str) -> dict:
        """The filtered state of one track (the `tracks/<id>` message body)."""
        arrays, row = self.store.where[track_id]
        return self.states(arrays, [row]).body(0)

    def snapshot(self, t: float, detail: bool = True) -> Any:
        """Every track as the display shows it at instant t (`display.DisplayState`)."""
        return self.display.snapshot(self.store, t, detail)
