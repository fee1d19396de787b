"""Measurements as columns, the input of the filter kernels: `MeasurementBatch.of`
turns the validated records of the wire contract (`zenoh_track.wire.Measurement`) into one
array per field, once per batch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..wire import Measurement, ScanColumns


@dataclass
class MeasurementBatch:
    """N measurements of one dimension d as columns: the filter core's input (the
    (N, d) arrays are column-major: the kernels read them a column at a time)."""

    t: np.ndarray  # (N,) s
    polar: np.ndarray  # (N,) bool: polar (r, az[, el]) or Cartesian position
    values: np.ndarray  # (N, d): (r, az[, el]) or the position
    sigmas: np.ndarray  # (N, d): (sr, saz[, sel]) or the std of each axis
    origin: np.ndarray  # (N, 3): sensor position
    # the conversion at the measured points, z (N, d) and R (N, d, d), once computed
    # (`ucm.at_point`): gating and initiation share it
    point: tuple[np.ndarray, np.ndarray] | None = None
    # or, for a batch taken from another (`take`), that one's conversion and the rows
    # taken: `at_point` takes them when first asked (a filter update never asks)
    point_of: tuple[tuple[np.ndarray, np.ndarray], np.ndarray] | None = None
    # (N,) s: the std of each measurement's time (`timing`; NaN: not stated, the noise
    # check may learn it), or None: no row states one
    sigma_t: np.ndarray | None = None

    @classmethod
    def of(cls, meas: Sequence[Measurement], dim: int) -> MeasurementBatch:
        """Columns of validated records (`validate.Measurement`) that all have dimension
        `dim` (values and sigmas of `dim` numbers each)."""
        n = len(meas)
        if not n:
            return cls(np.zeros(0), np.zeros(0, bool), np.zeros((0, dim), order="F"),
                       np.zeros((0, dim), order="F"), np.zeros((0, 3)))
        vals, sigs = [m.values for m in meas], [m.sigmas for m in meas]
        if set(map(len, vals)) | set(map(len, sigs)) != {dim}:
            raise ValueError(f"measurements of mixed dimensions in one {dim}-D batch")
        # flat lists axis by axis (much faster than from a list of tuples): (d, N)
        # arrays, whose transposes are the column-major (N, d) columns
        values = np.array([v[k] for k in range(dim) for v in vals], dtype=float)
        sigmas = np.array([v[k] for k in range(dim) for v in sigs], dtype=float)
        first = meas[0].sensor_pos
        origin = np.empty((n, 3))
        if all(m.sensor_pos == first for m in meas):  # one sensor: one row repeated
            origin[:] = first
        else:
            origin[:] = [m.sensor_pos for m in meas]
        sigma_t = None
        if any(m.sigma_t is not None for m in meas):
            sigma_t = np.array([np.nan if m.sigma_t is None else m.sigma_t for m in meas])
        return cls(np.array([m.t for m in meas], dtype=float),
                   np.array([m.polar for m in meas], dtype=bool), values.reshape(dim, n).T,
                   sigmas.reshape(dim, n).T, origin, sigma_t=sigma_t)

    @classmethod
    def of_scan(cls, scan: ScanColumns) -> MeasurementBatch:
        """Columns of the good rows of a checked batched scan (`wire.parse_scan_columns`),
        in order: the same as `of` on the scan's records (tests/test_scan_batch.py)."""
        n, good = scan.n, np.asarray(scan.good, dtype=np.intp)
        every = len(good) == n

        def column(v: list[float] | np.ndarray | float) -> np.ndarray:
            a = np.full(n, float(v)) if isinstance(v, int | float) else \
                np.asarray(v, dtype=float)
            return a if every else a[good]

        k, d = len(good), scan.dim
        values, sigmas = np.empty((k, d), order="F"), np.empty((k, d), order="F")
        for i in range(d):
            values[:, i], sigmas[:, i] = column(scan.values[i]), column(scan.sigmas[i])
        origin = np.empty((k, 3))
        origin[:] = scan.sensor_pos
        polar = np.full(k, scan.polar)
        stated = scan.sigma_t is not None or any(r.sigma_t is not None
                                                 for r in scan.fixed.values())
        sigma_t = (column(np.nan if scan.sigma_t is None else scan.sigma_t) if stated
                   else None)
        for row, rec in scan.fixed.items():  # rows the full check accepted as they are
            j = int(np.searchsorted(good, row))
            values[j], sigmas[j], origin[j], polar[j] = (rec.values, rec.sigmas,
                                                         rec.sensor_pos, rec.polar)
            if sigma_t is not None:
                sigma_t[j] = np.nan if rec.sigma_t is None else rec.sigma_t
        return cls(column(scan.t), polar, values, sigmas, origin, sigma_t=sigma_t)

    @classmethod
    def joined(cls, parts: Sequence[MeasurementBatch]) -> MeasurementBatch:
        """The measurements of `parts` (of one dimension), in order."""
        if len(parts) == 1:
            return parts[0]
        sigma_t = None
        if any(p.sigma_t is not None for p in parts):
            sigma_t = np.concatenate([np.full(len(p), np.nan) if p.sigma_t is None
                                      else p.sigma_t for p in parts])
        return cls(np.concatenate([p.t for p in parts]),
                   np.concatenate([p.polar for p in parts]),
                   np.asfortranarray(np.concatenate([p.values for p in parts])),
                   np.asfortranarray(np.concatenate([p.sigmas for p in parts])),
                   np.concatenate([p.origin for p in parts]), sigma_t=sigma_t)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dim(self) -> int:
        return self.values.shape[1]

    def take(self, index: Sequence[int] | np.ndarray) -> MeasurementBatch:
        """The measurements at `index`, in that order."""
        i = np.asarray(index, dtype=int)
        point_of = None if self.point is None else (self.point, i)
        # the column-major (N, d) columns taken as columns of their (d, N) transposes:
        # the result is column-major without a second copy
        return MeasurementBatch(self.t[i], self.polar[i], self.values.T.take(i, 1).T,
                                self.sigmas.T.take(i, 1).T, self.origin[i], None, point_of,
                                None if self.sigma_t is None else self.sigma_t[i])

    def tiled(self, m: int) -> MeasurementBatch:
        """The batch m times over, one copy after another."""
        return MeasurementBatch(np.tile(self.t, m), np.tile(self.polar, m),
                                np.asfortranarray(np.tile(self.values, (m, 1))),
                                np.asfortranarray(np.tile(self.sigmas, (m, 1))),
                                np.tile(self.origin, (m, 1)),
                                sigma_t=None if self.sigma_t is None
                                else np.tile(self.sigma_t, m))

    def rows(self, lo: int, hi: int) -> MeasurementBatch:
        point = None if self.point is None else (self.point[0][lo:hi], self.point[1][lo:hi])
        point_of = None if self.point_of is None else (self.point_of[0],
                                                       self.point_of[1][lo:hi])
        return MeasurementBatch(self.t[lo:hi], self.polar[lo:hi], self.values[lo:hi],
                                self.sigmas[lo:hi], self.origin[lo:hi], point, point_of,
                                None if self.sigma_t is None else self.sigma_t[lo:hi])
