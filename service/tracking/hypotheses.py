"""What an associator returns (`protocols.Associator`): one scan part's associations,
as indices into its rows, and the tracks it could have seen."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .store import TrackArrays

EMPTY = np.zeros(0, dtype=np.intp)


@dataclass
class WeightedUpdate:
    """Tracks of one layout each updated by an equivalent measurement z (T, d) with
    covariance r (T, d, d) standing for several weighted detections (`jpda.pda`),
    with the spread of those detections (T, n, n) added to the posterior covariance;
    `mass`: each track's probability of having been detected. The detections themselves,
    for a filter that updates by them (an IMM, mode by mode: `estimation.pda`): pair k of
    track `ti[k]` (an index into rows), detection `pz[k]` with covariance `pr[k]` and
    probability `beta[k]`; the sensor's `pd` and clutter density `lam`."""

    arrays: TrackArrays
    rows: np.ndarray
    z: np.ndarray
    r: np.ndarray
    mass: np.ndarray
    spread: np.ndarray
    ti: np.ndarray
    pz: np.ndarray
    pr: np.ndarray
    beta: np.ndarray
    pd: float
    lam: float


@dataclass
class Seen:
    """Tracks of one layout that a scan could have seen: which it `detected` (else
    missed), the log-likelihood ratio each gains (`life.update_life`, M of N) and what a
    miss weighs (the deletion's evidence)."""

    arrays: TrackArrays
    rows: np.ndarray
    detected: np.ndarray  # (T,) bool
    gain: np.ndarray  # (T,)
    miss: float  # ln(1 - Pd) of the scan's sensor: what a miss weighs against the track


@dataclass
class Hypotheses:
    """One scan part's associations (its measurements are of dimension `dim`), as
    indices into its rows: the measurements that update a track and those tracks' rows
    (in `store.layout(dim)`; an associator may add pairs in several stages), the tracks
    updated by weighted detections (JPDA), the measurements that start tracks, the ones
    rejected with their reasons, and the unlabelled tracks in view (M of N)."""

    dim: int
    index: list[np.ndarray] = field(default_factory=list)
    rows: list[np.ndarray] = field(default_factory=list)
    weighted: list[WeightedUpdate] = field(default_factory=list)
    unassociated: list[int] = field(default_factory=list)
    rejected: dict[int, str] = field(default_factory=dict)
    seen: list[Seen] = field(default_factory=list)
    # rows whose columns a stage put back (a second look's branch): drawn afresh
    moved: list[tuple[TrackArrays, np.ndarray]] = field(default_factory=list)

    def assign(self, index: np.ndarray, rows: np.ndarray) -> None:
        """Measurements `index` update the tracks at `rows`, pair by pair."""
        self.index.append(index)
        self.rows.append(rows)

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Every (measurement, row) pair assigned, as two arrays."""
        if len(self.index) == 1:
            return self.index[0], self.rows[0]
        if not self.index:
            return EMPTY, EMPTY
        return np.concatenate(self.index), np.concatenate(self.rows)
