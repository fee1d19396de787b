"""Track initiation: a new track from a measurement no track has claimed."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np

from ..estimation.measurements import MeasurementBatch
from ..estimation.ucm import at_point
from .store import TrackArrays, TrackStore


@functools.lru_cache(maxsize=16)
def _prior(speed: float, accel: float, order: int, dim: int) -> np.ndarray:
    """The initial covariance but for its position block: diag(0, speed^2[, accel^2])
    per axis."""
    return np.diag(np.repeat([0.0, speed**2, accel**2][:order], dim))


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
        finite = np.logical_and.reduce(
            np.isfinite(np.concatenate([z, r.reshape(len(r), dim * dim)], axis=1)), axis=1)
        speed = self.init_speed if speed is None else speed
        ok = finite.tolist()
        every = all(ok)
        arrays, rows = store.add_many(names if every else
                                      [k for k, good in zip(names, ok, strict=True) if good],
                                      dim)
        if not every:
            z, r, t = z[finite], r[finite], batch.t[finite]
        else:
            t = batch.t
        x = np.zeros((len(rows), arrays.n))
        x[:, :dim] = z
        p = np.empty((len(rows), arrays.n, arrays.n))
        p[:] = _prior(speed, self.init_accel, arrays.order, dim)
        p[:, :dim, :dim] = r
        arrays.x[rows], arrays.p[rows] = x, p
        arrays.t[rows] = arrays.t_first[rows] = t
        arrays.updates[rows] = 1
        arrays.nis[rows] = 0.0
        reasons = [None if good else "conversion gave a non-finite value" for good in ok]
        return arrays, rows, reasons
