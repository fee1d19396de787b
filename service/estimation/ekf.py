"""The EKF baseline's measurement terms (docs/scenarios.md, B): polar measurements kept polar
and linearised at the prediction; the CMKF's converted measurements are in `ucm`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .measurements import MeasurementBatch
from .polar import polar_linearised
from .timing import stated, time_noise
from .ucm import cmkf_arrays


def ekf_arrays(batch: MeasurementBatch, pred: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Polar measurements kept polar (z, R = diag of the noise variances), with the
    Jacobian h and predicted measurement hx at the predicted position pred (N, d);
    Cartesian ones as in the CMKF (h = I, hx = position)."""
    dim = batch.dim
    z, r = cmkf_arrays(batch, None)
    h = np.broadcast_to(np.eye(dim), (len(batch), dim, dim)).copy()
    hx = pred.copy()
    polar = batch.polar
    if polar.any():
        origin, sig = batch.origin[polar, :dim], batch.sigmas[polar]
        hx[polar], h[polar], z[polar] = polar_linearised(pred[polar] - origin,
                                                         batch.values[polar])
        r[polar] = sig[:, :, None] ** 2 * np.eye(dim)
    return z, r, h, hx


@dataclass
class EKFConversion:
    """The measurements of a batch for the filters (`filters.Convert`): called with
    predicted states xp (N, n) and covariances pp it returns z, R, h, hx (`ekf_arrays`)."""

    batch: MeasurementBatch

    def __call__(self, xp: np.ndarray, pp: np.ndarray) -> tuple:
        d, b = self.batch.dim, self.batch
        z, r, h, hx = ekf_arrays(b, xp[:, :d])
        if stated(b.sigma_t):  # the time's noise (the mixture's variance): the velocity
            # seen through the Jacobian
            v = slice(d, 2 * d)
            ht = h.transpose(0, 2, 1)
            r = time_noise(r, (h @ xp[:, v, None])[:, :, 0], h @ pp[:, v, v] @ ht,
                           b.sigma_t)
        return z, r, h, hx
