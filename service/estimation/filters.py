"""Filters over a layout of tracks: how one batch of rows is predicted and updated.

Every filter works on stacked arrays (rows of a `tracking.store.TrackArrays`) and
returns the output estimate (x, P) of each row; the tracker stores it and the display
state predicts it. `SingleModelFilter` is one model (the CMKF, or the EKF baseline);
`imm.IMM` mixes several models; `vdf.VDF` switches between CV and CA on a manoeuvre
detector. In the tracker loop a filter is the updater (Stone Soup's word): prediction
and update are fused per batch. Pure NumPy, no Zenoh.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from . import kalman, models, scratch, timing
from .batch import einsum
from .measurements import MeasurementBatch
from .ucm import CMKFConversion, cmkf_soa

# (x_pred (N, n), P_pred (N, n, n)) -> (z, R[, h, hx]) converted for those predictions
Convert = Callable[[np.ndarray, np.ndarray], tuple]


Result = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # x, P, nis, ok


class Rows(Protocol):
    """What a filter reads and writes of a layout of tracks (`tracking.store.TrackArrays`):
    its dimension and model order, the stacked states x (cap, n), covariances p
    (cap, n, n) and update times t, and the per-row fields the filter declared
    (`fields`), by name."""

    dim: int
    order: int
    x: np.ndarray
    p: np.ndarray
    t: np.ndarray

    def __getattr__(self, name: str) -> np.ndarray: ...


@dataclass(frozen=True)
class SingleModelFilter:
    """One motion model ("cv" or "ca") with the CMKF, or the EKF on polar input."""

    # no gate of its own: the tracks are gated with their state and the display's q
    gate_prediction: ClassVar[None] = None

    kind: str = "cv"
    q: float = 1.0
    order: int = 2

    @property
    def fields(self) -> dict[str, tuple]:
        """Per-row arrays this filter keeps in the track store: none."""
        return {}

    def initiate(self, arrays: Rows, rows: np.ndarray) -> None:
        """Nothing beyond the table's own x and P."""

    def update(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray, convert: Convert) -> Result:
        standard = (self.kind, self.order) in (("cv", 2), ("ca", 3))  # F, Q of models.predict
        cmkf = isinstance(convert, CMKFConversion)
        if standard and cmkf and not timing.stated(convert.batch.sigma_t):
            return cmkf_step(arrays.x[rows], arrays.p[rows], dt, self.order, arrays.dim, self.q,
                             convert.batch)
        if standard:
            xp, pp = models.predict(arrays.x[rows], arrays.p[rows], dt, self.order, arrays.dim,
                                    self.q)
        else:
            f, qm = models.motion(self.kind, dt, self.order, arrays.dim, self.q)
            xp, pp = predict(arrays.x[rows], arrays.p[rows], f, qm)
        if cmkf:  # the time's noise a mixture (`timing.mixture_update`)
            z, r, term, some = convert.parts(xp, pp)
            if term is not None:
                x, p, ok, _ = timing.mixture_update(kalman.update_full, xp, pp, z, r, term,
                                                    some)
                return x, p, kalman.update(xp, pp, z, r + term)[2], ok
        return kalman.update(xp, pp, *convert(xp, pp))

    def update_pda(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray, weighted: Any
                   ) -> None:
        """No update by weighted detections of its own: the tracker's equivalent
        measurement serves."""
        return None

    def inflate(self, arrays: Rows, rows: np.ndarray, dp: np.ndarray) -> None:
        """The tracker added dp to the covariances of rows: nothing more is kept."""

    def labels(self, arrays: Rows, rows: np.ndarray) -> list[str]:
        return [self.kind] * len(rows)


def cmkf_step(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
              q: float | np.ndarray, batch: MeasurementBatch) -> Result:
    """The filter core: prediction (`models.predict_soa`), conversion of the measurements
    at the prediction (`ucm.cmkf_soa`) and CMKF update (`kalman.update_soa`) of rows
    x (N, n), P (N, n, n) over their own dt, in one pass per chunk of rows on batch-last
    work arrays. Returns new arrays: posterior x, P, NIS and the mask of finite rows."""
    n_rows, n = x.shape
    dt = np.asarray(dt, dtype=float)
    if dt.shape != (n_rows,):
        dt = np.broadcast_to(dt, (n_rows,))
    q = np.asarray(q, dtype=float)
    xn, pn = np.empty((n_rows, n)), np.empty((n_rows, n, n))
    nis, det = np.empty(n_rows), np.empty(n_rows)
    ok = np.empty(n_rows, dtype=bool)
    if n_rows <= scratch.CHUNK:  # one chunk (most calls): no slicing of anything
        _step_chunk(x, p, dt, order, dim, q, batch, xn, pn, nis, det, ok)
        return xn, pn, nis, ok
    for lo, hi in scratch.chunks(n_rows):
        _step_chunk(x[lo:hi], p[lo:hi], dt[lo:hi], order, dim, q[lo:hi] if q.ndim else q,
                    batch.rows(lo, hi), xn[lo:hi], pn[lo:hi], nis[lo:hi], det[lo:hi],
                    ok[lo:hi])
    return xn, pn, nis, ok


def _step_chunk(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
                q: np.ndarray, batch: MeasurementBatch, xn: np.ndarray, pn: np.ndarray,
                nis: np.ndarray, det: np.ndarray, ok: np.ndarray) -> None:
    """`cmkf_step` on one chunk of rows, into xn, pn, nis, det and ok."""
    k, n = x.shape
    xs = scratch.to_soa(x, "step.x")
    blocks = models.to_blocks(p, order, dim, scratch.buffer("step.pb", (order, order, dim,
                                                                      dim), k))
    ps = scratch.buffer("step.p", (n, n), k)
    models.predict_blocks(xs, blocks, dt, order, dim, q, ps)
    zs, rs = scratch.buffer("step.z", (dim,), k), scratch.buffer("step.r", (dim, dim), k)
    cmkf_soa(batch, xs[:dim], ps[:dim, :dim], zs, rs)
    pout = scratch.buffer("step.pn", (n, n), k)
    kalman.update_soa(xs, ps, zs, rs, pout, nis, det)
    ok[:] = kalman.finite(xs, pout, nis, dim)
    np.copyto(xn.T, xs)
    np.copyto(scratch.batch_last(pn), pout)


def predict(x: np.ndarray, p: np.ndarray, f: np.ndarray, q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """x (N, n), P (N, n, n) predicted by full transition matrices F and noise Q (N, n, n)."""
    xp = (f @ x[:, :, None])[:, :, 0]  # matmul: much faster than einsum on small matrices
    return xp, kalman.symmetrise(f @ p @ f.transpose(0, 2, 1) + q)


def moments(x: np.ndarray, p: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of Gaussian mixtures: x (N, M, n), P (N, M, n, n), w (N, M)."""
    mean = einsum("nm,nmi->ni", w, x)
    d = x - mean[:, None]
    cov = einsum("nm,nmij->nij", w, p + d[..., :, None] * d[..., None, :])
    return mean, kalman.symmetrise(cov)
