"""The conversion at the measured points (`ucm.at_point`: an unlabelled scan's gate and
the tracks it starts) by a compiled kernel once the kernels serve (`estimation.jit`);
`ucm.cmkf_arrays(batch, None)` until then, and its reference."""

from __future__ import annotations

import numpy as np

from . import jit
from .measurements import MeasurementBatch
from .ucm import at_point as at_point_plain

__all__ = ["at_point", "warm"]


def at_point(batch: MeasurementBatch) -> tuple[np.ndarray, np.ndarray]:
    """`ucm.at_point`, computed once per batch and kept in `batch.point`: by
    `ucm_kernel.at_points` when the kernels serve."""
    if batch.point is not None or batch.point_of is not None or not jit.ready():
        return at_point_plain(batch)
    batch.point = compiled(batch)
    return batch.point


def compiled(batch: MeasurementBatch) -> tuple[np.ndarray, np.ndarray]:
    """z (N, d) and R (N, d, d) of every row by the compiled kernel."""
    from .ucm_kernel import at_points

    n, d = batch.values.shape
    z, r = np.empty((n, d)), np.empty((n, d, d))
    c = np.ascontiguousarray  # one layout, one compiled form (the columns are column-major)
    at_points(c(batch.polar, np.bool_), c(batch.values, float), c(batch.sigmas, float),
              c(batch.origin, float), z, r)
    return z, r


def warm() -> None:
    """Compile the kernel (or load it from the cache): `jit.prepare`'s child."""
    for d in (2, 3):
        compiled(MeasurementBatch(np.zeros(2), np.array([True, False]),
                                  np.ones((2, d), order="F"), np.ones((2, d), order="F"),
                                  np.zeros((2, 3))))
