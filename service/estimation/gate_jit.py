"""An unlabelled scan's gate by compiled kernels once the kernels serve
(`estimation.jit`; `gate_kernel`): the conversion at the measured points (`ucm.at_point`,
shared with the tracks the scan starts), the pairs' distances and the IMM's pair
likelihood. Each has its NumPy form, which serves until then and is its reference."""

from __future__ import annotations

import numpy as np

from . import jit
from .measurements import MeasurementBatch
from .ucm import at_point as at_point_plain

__all__ = ["at_point", "gate_pairs", "mixture", "warm"]


def at_point(batch: MeasurementBatch) -> tuple[np.ndarray, np.ndarray]:
    """`ucm.at_point`, computed once per batch and kept in `batch.point`: by
    `gate_kernel.at_points` when the kernels serve."""
    if batch.point is not None or batch.point_of is not None or not jit.ready():
        return at_point_plain(batch)
    batch.point = compiled(batch)
    return batch.point


def compiled(batch: MeasurementBatch) -> tuple[np.ndarray, np.ndarray]:
    """z (N, d) and R (N, d, d) of every row by the compiled kernel."""
    from .gate_kernel import at_points

    n, d = batch.values.shape
    z, r = np.empty((n, d)), np.empty((n, d, d))
    c = np.ascontiguousarray  # one layout, one compiled form (the columns are column-major)
    at_points(c(batch.polar, np.bool_), c(batch.values, float), c(batch.sigmas, float),
              c(batch.origin, float), z, r)
    return z, r


def gate_pairs(ti: np.ndarray, dj: np.ndarray, z: np.ndarray, mean_s: np.ndarray,
               cross_s: np.ndarray, r: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs' innovations (K, d), squared Mahalanobis distances and det S by
    `gate_kernel.gate_pairs` (the caller checks `jit.ready()`)."""
    from .gate_kernel import gate_pairs as kernel

    k, d = len(ti), z.shape[1]
    nu, d2, det = np.empty((k, d)), np.empty(k), np.empty(k)
    c = np.ascontiguousarray
    kernel(c(ti, np.int64), c(dj, np.int64), c(z, float), c(mean_s, float), c(cross_s, float),
           c(r, float), nu, d2, det)
    return nu, d2, det


def mixture(loglik: np.ndarray, ti: np.ndarray, nu: np.ndarray, r: np.ndarray,
            narrow: np.ndarray, w: np.ndarray) -> np.ndarray:
    """`IMM.gate_prediction`'s pair likelihood by `gate_kernel.mixture` (the caller checks
    `jit.ready()`)."""
    from .gate_kernel import mixture as kernel

    out = np.empty(len(ti))
    c = np.ascontiguousarray
    kernel(c(loglik, float), c(ti, np.int64), c(nu, float), c(r, float), c(narrow, float),
           c(w, float), out)
    return out


def warm() -> None:
    """Compile the kernels (or load them from the cache): `jit.prepare`'s child."""
    for d in (2, 3):
        compiled(MeasurementBatch(np.zeros(2), np.array([True, False]),
                                  np.ones((2, d), order="F"), np.ones((2, d), order="F"),
                                  np.zeros((2, 3))))
        one, eye = np.zeros(1, np.int64), np.eye(d)[None]
        gate_pairs(one, one, np.zeros((1, d)), np.zeros((d, 1)),
                   np.eye(d, 3 * d)[:, :, None] * 1.0, eye)
        mixture(np.zeros(1), one, np.zeros((1, d)), eye, eye, np.full(1, 0.5))
