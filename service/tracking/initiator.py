"""Track initiation: a new track from a measurement no track has claimed."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..estimation.measurements import MeasurementBatch
from ..estimation.ucm import at_point
from .store import TrackArrays, TrackStore


class SinglePointInitiator:
    """One-point initiation: position from the converted measurement (UCM at the
    measured point for polar ones), velocity (and acceleration) zero with a wide prior of
    std `init_speed` (`init_accel`); the second measurement then gives the two-point
    difference in the limit of a diffuse prior (Mallick & La Scala, 'Comparison of
    single-point and two-point difference track initiation', 2008)."""

    def __init__(self, init_speed: float, init_accel: float) -> None:
        self.init_speed, self.init_accel = init_speed, init_accel

    def initiate(self, store: TrackStore, dim: int, batch: MeasurementBatch,
                 names: Sequence[str], speed: float | None = None
                 ) -> tuple[TrackArrays, np.ndarray, list[str | None]]:
        """New tracks, one per measurement of `batch`, named by `names`: the layout, the
        rows created and, per measurement, None or the reason it started no track.
        `speed`: the velocity prior's std instead of `init_speed`."""
        arrays = store.layout(dim)
        z, r = at_point(batch)  # shared with the gate of an unlabelled scan
        finite = np.isfinite(z).all(1) & np.isfinite(r).all((1, 2))
        speed = self.init_speed if speed is None else speed
        prior = [speed**2, self.init_accel**2][: arrays.order - 1]
        ok = finite.tolist()
        arrays, rows = store.add_many([k for k, good in zip(names, ok, strict=True) if good],
                                      dim)
        arrays.x[rows] = 0.0
        arrays.x[rows, :dim] = z[finite]
        arrays.p[rows] = np.diag(np.repeat([0.0, *prior], dim))
        arrays.p[rows, :dim, :dim] = r[finite]
        arrays.t[rows] = arrays.t_first[rows] = batch.t[finite]
        arrays.updates[rows] = 1
        arrays.nis[rows] = 0.0
        reasons = [None if good else "conversion gave a non-finite value" for good in ok]
        return arrays, rows, reasons
