"""Track status: tentative until the track is established, confirmed, and coasting
while measurements are overdue or missed (the contract's `status`,
`zenoh_track.wire.STATUSES`)."""

from __future__ import annotations

import numpy as np

from .store import TrackArrays

TENTATIVE, CONFIRMED, COASTING = range(3)  # indices into wire.STATUSES


def status_codes(arrays: TrackArrays, rows: np.ndarray | slice, age: np.ndarray,
                 coast_after: float) -> np.ndarray:
    """Status of rows, as indices into STATUSES.

    Labelled tracks: tentative until they have as many updates as their model order (the
    state is determined), coasting once their age exceeds `coast_after` x their mean
    interval between updates, else confirmed. Tracks of unlabelled scans: tentative until
    confirmed M of N (`life.update_life`), coasting while their last scans missed them,
    else confirmed."""
    updates = arrays.updates[rows]
    interval = np.where(updates > 1, (arrays.t[rows] - arrays.t_first[rows])
                        / np.maximum(updates - 1, 1), np.inf)
    coasting = age > coast_after * interval
    labelled = np.where(coasting, COASTING, (updates >= arrays.order).astype(np.int8))
    plot = arrays.plot[rows]
    if not plot.any():
        return labelled
    scans = np.where(arrays.misses[rows] > 0, COASTING, CONFIRMED)
    scans = np.where(arrays.confirmed[rows], scans, TENTATIVE)
    return np.where(plot, scans, labelled)
