"""Data association: which measurement updates which track.

`LabelAssociator` serves labelled measurements (`<ns>/meas/<sensor>/<target>`): the
label names the track. Associators for unlabelled detections (GNN, JPDA) take the same
slot in the tracker loop (`tracker.Tracker.step`) and return the same `Hypotheses`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import repeat
from operator import itemgetter

import numpy as np

from ..estimation.measurements import MeasurementBatch
from ..wire import Measurement
from .store import TrackArrays, TrackStore

TIME_TOL = 1e-6  # s: measurements this close to the track time count as simultaneous


@dataclass
class WeightedUpdate:
    """Tracks of one layout each updated by an equivalent measurement z (T, d) with
    covariance r (T, d, d) standing for several weighted detections (`association.pda`),
    with the spread of those detections (T, n, n) added to the posterior covariance;
    `mass`: each track's probability of having been detected."""

    arrays: TrackArrays
    rows: np.ndarray
    z: np.ndarray
    r: np.ndarray
    mass: np.ndarray
    spread: np.ndarray


@dataclass
class Seen:
    """Tracks of one layout that a scan could have seen: which it `detected` (else
    missed) and the log-likelihood ratio each gains (`life.update_life`, M of N)."""

    arrays: TrackArrays
    rows: np.ndarray
    detected: np.ndarray  # (T,) bool
    gain: np.ndarray  # (T,)


@dataclass
class Hypotheses:
    """One scan's associations, as indices into the scan's measurements."""

    updates: dict[int, list[int]] = field(default_factory=dict)  # by dimension: measurements
    tracks: dict[int, list[str]] = field(default_factory=dict)  # ... and the track each updates
    rows: dict[int, list[np.ndarray]] = field(default_factory=dict)  # ... or its store rows
    weighted: list[WeightedUpdate] = field(default_factory=list)  # JPDA's updates
    unassociated: dict[int, list[int]] = field(default_factory=dict)  # by dimension: new
    rejected: dict[int, str] = field(default_factory=dict)  # index -> reason
    seen: list[Seen] = field(default_factory=list)  # unlabelled tracks in view (M of N)
    columns: MeasurementBatch | None = None  # the scan as columns, if the associator made them

    def batch(self, meas: Sequence[Measurement], dim: int, index: list[int]
              ) -> MeasurementBatch:
        """The measurements meas[index] (all of dimension `dim`) as columns."""
        if self.columns is not None:
            return self.columns.take(index)
        return MeasurementBatch.of([meas[i] for i in index], dim)


class LabelAssociator:
    """A measurement belongs to the track its label names; a label with no track starts
    one. A measurement for a track of the other dimension, older than the track's last
    update (labelled tracks are not retrodicted), or a duplicate (the same sensor at the
    same time as the track's last update) is rejected. Labelled measurements do
    not say which tracks a sensor missed, so `seen` stays empty: the tracks' status
    follows from their age (`status`)."""

    def __init__(self) -> None:
        self.last: dict[str, str] = {}  # track -> the sensor of its last update

    def forget(self, ids: Sequence[str]) -> None:
        """Tracks deleted: drop what is kept of them."""
        for track_id in ids:
            self.last.pop(track_id, None)

    def scans(self, meas: Sequence[Measurement]) -> list[list[int]]:
        """Split a batch into scans in which each target appears at most once, keeping
        order: a target measured twice in a batch is updated twice, in turn."""
        return split_repeats([m.target for m in meas])

    def associate_columns(self, store: TrackStore, ids: Sequence[str],
                          sensor: str | Sequence[str], t: np.ndarray, dim: int
                          ) -> tuple[np.ndarray, np.ndarray, list[int], dict[int, str]]:
        """`associate` for measurements of dimension `dim` given as columns (ids, times t;
        `sensor`: of all of them, or of each), each target at most once: the indices of
        the measurements that update a track and those tracks' rows (in
        `store.layout(dim)`), the indices of the new targets and the rejected ones with
        their reasons (the same as `associate`'s)."""
        sensors = repeat(sensor) if isinstance(sensor, str) else sensor
        where, last = store.where, self.last
        arrays = store.layouts.get(dim)
        hits = list(map(where.get, ids))
        upd: list[int] = []
        rows: list[int] = []
        new: list[int] = []
        rejected: dict[int, str] = {}
        if None not in hits and len(store.layouts) == 1 and arrays is not None:
            upd, rows = list(range(len(ids))), list(map(itemgetter(1), hits))  # all tracked
        else:
            for i, hit in enumerate(hits):
                if hit is None:
                    new.append(i)
                elif hit[0] is arrays:
                    upd.append(i)
                    rows.append(hit[1])
                else:
                    rejected[i] = f"{dim}-D measurement for a {hit[0].dim}-D track"
        ui, ri = np.array(upd, dtype=np.intp), np.array(rows, dtype=np.intp)
        if len(ri):
            tt, mt = arrays.t[ri], t[ui]  # type: ignore[union-attr]
            late = mt < tt - TIME_TOL
            near = ~late & (mt <= tt + TIME_TOL)
            if late.any() or near.any():
                for j in np.flatnonzero(late | near).tolist():
                    i = upd[j]
                    if late[j]:
                        rejected[i] = (f"out of sequence: t={mt[j]:.6f} is before the track's "
                                       f"last update at t={tt[j]:.6f}")
                    elif last.get(ids[i]) == (sn := _at(sensor, i)):
                        rejected[i] = (f"duplicate: sensor {sn} already measured this "
                                       f"target at t={mt[j]:.6f}")
                keep = np.array([i not in rejected for i in upd], dtype=bool)
                ui, ri = ui[keep], ri[keep]
        if not rejected:
            last.update(zip(ids, sensors, strict=False))  # sensors may repeat one
        else:
            last.update((ids[i], _at(sensor, i)) for i in (*ui.tolist(), *new))
        return ui, ri, new, rejected

    def associate(self, store: TrackStore, scan: Sequence[Measurement],
                  now: float | None = None) -> Hypotheses:
        hyp = Hypotheses()
        last = self.last
        for i, m in enumerate(scan):
            hit = store.where.get(m.target)
            if hit is None:
                hyp.unassociated.setdefault(m.dim, []).append(i)
                last[m.target] = m.sensor
                continue
            arrays, row = hit
            if arrays.dim != m.dim:
                hyp.rejected[i] = f"{m.dim}-D measurement for a {arrays.dim}-D track"
            elif m.t < arrays.t[row] - TIME_TOL:
                hyp.rejected[i] = (f"out of sequence: t={m.t:.6f} is before the track's last "
                                   f"update at t={arrays.t[row]:.6f}")
            elif m.t <= arrays.t[row] + TIME_TOL and last.get(m.target) == m.sensor:
                hyp.rejected[i] = (f"duplicate: sensor {m.sensor} already measured this "
                                   f"target at t={m.t:.6f}")
            else:
                hyp.updates.setdefault(m.dim, []).append(i)
                hyp.tracks.setdefault(m.dim, []).append(m.target)
                last[m.target] = m.sensor
        return hyp


def _at(sensor: str | Sequence[str], i: int) -> str:
    """The sensor of measurement i (`sensor`: of all, or of each)."""
    return sensor if isinstance(sensor, str) else sensor[i]


def split_repeats(keys: Sequence[str]) -> list[list[int]]:
    """Indices of `keys` split into runs in which each key appears at most once, in order:
    the first occurrence of every key, then the second ones, and so on."""
    if len(set(keys)) == len(keys):
        return [list(range(len(keys)))] if len(keys) else []
    out: list[list[int]] = []
    pending = list(range(len(keys)))
    while pending:
        seen: set[str] = set()
        now, later = [], []
        for i in pending:
            (later if keys[i] in seen else now).append(i)
            seen.add(keys[i])
        out.append(now)
        pending = later
    return out
