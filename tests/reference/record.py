"""The tracker loop one measurement record at a time: the tests' reference for
`Tracker.step` on columns (tests/test_scan_batch.py), and a convenient way for unit
tests to feed `wire.Measurement` records and read one `Outcome` per measurement.

Labelled measurements are associated record by record (the textbook's loop: look the
label up, check the dimension, the order in time and duplicates) and applied through
the tracker's public stages (`update`, `delete`, `initiate`); unlabelled scans go
through `Tracker.step` and their outcomes are spread back over the detections.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.tracking.batches import Unlabelled
from zenoh_track.tracking.label_association import (
    duplicate,
    out_of_sequence,
    split_repeats,
    wrong_dimension,
)
from zenoh_track.tracking.store import States
from zenoh_track.tracking.tracker import NON_FINITE, Tracker
from zenoh_track.wire import TIME_TOL, Measurement, PlotScan


@dataclass
class Outcome:
    """What became of one measurement."""

    meas: Measurement
    reason: str | None = None  # None: accepted
    nis: float = float("nan")
    states: States | None = None  # accepted: the tracks updated with it, this one among them


def track(tracker: Tracker, measurements: Sequence[Measurement]
          ) -> tuple[list[Outcome], list[str]]:
    """Apply labelled measurements in order, one `step` per scan in which each target
    appears at most once: each measurement's outcome, and the tracks deleted."""
    outcomes = [Outcome(m) for m in measurements]
    deleted: list[str] = []
    for scan in split_repeats([m.target for m in measurements]):
        deleted += step(tracker, [outcomes[i] for i in scan])
    return outcomes, deleted


def step(tracker: Tracker, scan: list[Outcome]) -> list[str]:
    """One scan of labelled records: associate each, update, delete, initiate."""
    store = tracker.store
    updates: dict[int, list[Outcome]] = {}
    new: dict[int, list[Outcome]] = {}
    for out in scan:
        m = out.meas
        hit = store.where.get(m.target)
        if hit is None:
            new.setdefault(m.dim, []).append(out)
            continue
        arrays, row = hit
        if arrays.dim != m.dim:
            out.reason = wrong_dimension(m.dim, arrays.dim)
        elif m.t < arrays.t[row] - TIME_TOL:
            out.reason = out_of_sequence(m.t, arrays.t[row])
        elif m.t <= arrays.t[row] + TIME_TOL and arrays.sensor[row] == m.sensor:
            out.reason = duplicate(m.sensor, m.t)
        else:
            updates.setdefault(m.dim, []).append(out)
            arrays.sensor[row] = m.sensor
    for dim, outs in updates.items():
        arrays = store.layout(dim)
        rows = np.array([store.where[o.meas.target][1] for o in outs], dtype=int)
        good, ok, nis = tracker.update(arrays, rows,
                                       MeasurementBatch.of([o.meas for o in outs], dim))
        block = tracker.states(arrays, good)
        for out, fine, v in zip(outs, ok.tolist(), nis.tolist(), strict=True):
            out.reason, out.nis, out.states = (None, v, block) if fine else \
                (NON_FINITE, np.nan, None)
    deleted = tracker.delete(max(o.meas.t for o in scan)) if scan else []
    for dim, outs in new.items():
        arrays, rows, reasons = tracker.initiate(
            dim, MeasurementBatch.of([o.meas for o in outs], dim), [o.meas.target for o in outs])
        block = tracker.states(arrays, rows)
        for out, reason in zip(outs, reasons, strict=True):
            if reason is None:
                arrays.sensor[store.where[out.meas.target][1]] = out.meas.sensor
            out.reason, out.nis = reason, 0.0 if reason is None else np.nan
            out.states = block if reason is None else None
    return deleted


def scan_step(tracker: Tracker, outcomes: list[Outcome], t: float) -> list[str]:
    """One unlabelled scan at time t of the detections of `outcomes` (one sensor):
    `Tracker.step`, each detection's reason filled in; the tracks deleted."""
    sensor = outcomes[0].meas.sensor if outcomes else "r1"
    got = tracker.step(Unlabelled.of(sensor, t, [o.meas for o in outcomes]))
    for i, reason in got.rejected:
        outcomes[i].reason = reason
    return got.deleted


def track_scan(tracker: Tracker, scan: PlotScan) -> tuple[list[Outcome], list[str]]:
    """A checked unlabelled scan (`wire.parse_plots`): each detection's outcome and the
    tracks deleted."""
    outcomes = [Outcome(m) for m in scan.detections]
    got = tracker.step(Unlabelled.of(scan.sensor, scan.t, scan.detections))
    for i, reason in got.rejected:
        outcomes[i].reason = reason
    return outcomes, got.deleted
