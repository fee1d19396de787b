"""What the display shows between updates: prediction, blended correction, or smoothing.

Pure NumPy over rows of a track bank. `predicted` dead-reckons the filtered state to the
display instant. `blended` keeps the drawn position continuous when a correction lands,
absorbing it at a limited speed and/or over a set period. `smoothed` serves a lagged
display: the fixed-interval (Rauch-Tung-Striebel) smoother between the two filtered
states that bracket the instant.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import kalman, models
from .clock import TOL


def predicted(bank: Any, rows: np.ndarray, t: np.ndarray | float, q: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives (N, order, dim) of each row's state predicted to t, and the variance
    (N,) summed over the position axes (trace of the predicted position covariance)."""
    d, o = bank.dim, bank.order
    dt = t - bank.t[rows]
    phi = models.axis_transition(dt, o)  # (N, o, o)
    xs = phi @ bank.x[rows].reshape(-1, o, d)  # matmul: ~5x faster than einsum here
    tr = bank.ptr[rows]  # (N, o, o): kept by the table at each update
    c0 = phi[:, 0, :]
    g0 = models.axis_noise_gain(np.abs(dt), o)[:, 0]
    var = d * (q * g0) ** 2  # c0' tr c0 term by term: small-axis reductions are slow
    for a in range(o):
        for b in range(o):
            var = var + c0[:, a] * c0[:, b] * tr[:, a, b]
    return xs, var


def axis_traces(p: np.ndarray, order: int, dim: int) -> np.ndarray:
    """(N, order, order): the covariances summed over the spatial axes, block by block
    (derivative i with derivative j); the position variance of a prediction follows from
    them without the full matrix."""
    return np.einsum("naibi->nab", p.reshape(-1, order, dim, order, dim))


def frame_before(t: np.ndarray, rate: float) -> np.ndarray:
    """The last display instant n / rate strictly before t (same tolerance as the clock)."""
    return (np.ceil((np.asarray(t, dtype=float) - TOL) * rate) - 1.0) / rate


def blend_period(offset: np.ndarray, period: float, speed: float) -> np.ndarray:
    """How long each row takes to absorb its correction offset (N, dim): |offset| / speed
    when a speed is set (slew-rate limit: the drawn point never moves faster than `speed`
    relative to the estimate, so small corrections vanish within a frame or two and only
    large ones take long), at most `period` when that is set too; `period` alone: every
    correction over the same period. No offset, no period."""
    size = np.linalg.norm(offset, axis=-1)
    if speed <= 0:
        return np.where(size > 0, float(period), 0.0)
    dur = size / speed
    return np.minimum(dur, period) if period > 0 else dur


def blended(bank: Any, rows: np.ndarray, t: np.ndarray | float, xs: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position drawn at t while a correction is absorbed: the new estimate's prediction xs
    plus the offset bo (what was drawn at bt minus the new estimate at bt) decaying
    linearly to zero over the row's period bd (`blend_period`; 0 for a new track, and for
    a correction that lands on a tentative track). Returns pos, vel (N, dim) and a mask
    of rows still blending.

    bt is the last display instant before the correction, so the frame at the correction
    instant already takes the first step, and every frame moves at most |bo| / (bd x rate)
    beyond the estimate's own motion. With a speed limit that step is the same for every
    correction (speed / rate), so the jump bound costs only the largest corrections time;
    a fixed period holds small corrections as long as large ones. Linear decay is the
    fastest schedule that keeps each frame's step under the bound. This is rate-limited
    convergence to the estimate, not projective velocity blending (Murphy, "Believable
    Dead Reckoning for Networked Games", Game Engine Gems 2, 2011): the new velocity is
    taken at once, so the old trajectory's velocity error stops counting straight away
    (docs/accuracy.md)."""
    tau = np.broadcast_to(np.asarray(t - bank.bt[rows], dtype=float), rows.shape)
    period = bank.bd[rows]
    s = np.clip(np.divide(tau, period, out=np.ones_like(tau), where=period > 0), 0.0, 1.0)
    return xs[:, 0] + bank.bo[rows] * (1.0 - s)[:, None], xs[:, 1], s < 1.0


def smoothed(bank: Any, rows: np.ndarray, t: float, q: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RTS smoothing of the instant t between the previous filtered state (px, pp at pt)
    and the current one (x at t_k): x_s = x_t + C (x_k - x_k^-), C = P_t F' (P_k^-)^-1.
    Returns pos, vel (N, dim) and the mask of rows bracketed by two updates."""
    d, o = bank.dim, bank.order
    ok = (bank.updates[rows] > 1) & (bank.pt[rows] <= t) & (t < bank.t[rows])
    pos = np.full((len(rows), d), np.nan)
    vel = pos.copy()
    r = rows[ok]
    if len(r):
        dt1, dt2 = t - bank.pt[r], bank.t[r] - t
        xt, pt = models.predict(bank.px[r], bank.pp[r], dt1, o, d, q)
        f2 = models.transition(dt2, o, d)
        xk = np.einsum("nij,nj->ni", f2, xt)
        pk = f2 @ pt @ f2.transpose(0, 2, 1) + models.process_noise(dt2, o, d, q)
        pk = kalman.symmetrise(pk) + kalman.S_FLOOR * np.eye(bank.n)
        gain = kalman.solve(pk, (pt @ f2.transpose(0, 2, 1)).transpose(0, 2, 1))
        xs = xt + np.einsum("nji,nj->ni", gain, bank.x[r] - xk)
        pos[ok], vel[ok] = xs[:, :d], xs[:, d:2 * d]
    return pos, vel, ok & np.isfinite(pos).all(1)
