"""Track status: tentative until the filter's state is determined, confirmed, and coasting
while measurements are overdue (the contract's `status`, `service.wire.STATUSES`)."""

from __future__ import annotations

import numpy as np

from .store import TrackArrays

TENTATIVE, CONFIRMED, COASTING = range(3)  # indices into wire.STATUSES


def status_codes(arrays: TrackArrays, rows: np.ndarray, age: np.ndarray,
                 coast_after: float) -> np.ndarray:
    """Status of rows, as indices into STATUSES: tentative until the track has as many
    updates as its model order (the state is determined), coasting once its age exceeds
    `coast_after` x its mean interval between updates, else confirmed."""
    updates = arrays.updates[rows]
    interval = np.where(updates > 1, (arrays.t[rows] - arrays.t_first[rows])
                        / np.maximum(updates - 1, 1), np.inf)
    coasting = age > coast_after * interval
    return np.where(coasting, COASTING, (updates >= arrays.order).astype(np.int8))
