"""The noise of a measurement's time in its covariance: a position stamped with a time
that is not quite its own is a position of the track a little earlier or later.

A measurement z stamped t but taken at t + e (e the time error, zero mean, variance
sigma_t^2, independent of the position noise) is, to first order, the position at t plus
v e, v the target's velocity: z = p(t) + v e + w, so its error covariance is
R + sigma_t^2 v v' (the time error projected along the path; Choi, Choi, Park & Chung,
"State estimation with delayed measurements considering uncertainty of time delay",
IEEE ICRA 2009; docs/timing.md). The velocity is known only as the prediction's,
N(v^, P_vv): averaged over it (as the converted measurement's R is averaged over the
predicted position, `ucm.ucm_expected_soa`) the term is sigma_t^2 (v^ v^' + P_vv). A
radar measurement's time error moves its converted point the same way, so the term is
added to the converted R of polar and Cartesian measurements alike. Pure NumPy.
"""

from __future__ import annotations

import numpy as np


def time_noise(r: np.ndarray, vel: np.ndarray, vel_cov: np.ndarray | None,
               sigma_t: np.ndarray) -> np.ndarray:
    """R (N, d, d) plus sigma_t^2 (v v' + P_vv) per row: vel (N, d) the predicted velocity,
    vel_cov (N, d, d) its covariance (None: taken as exact), sigma_t (N,) s (NaN or 0: no
    time noise, the row's R unchanged). A new array."""
    s2 = np.square(np.nan_to_num(np.asarray(sigma_t, dtype=float), nan=0.0))
    out = r + s2[:, None, None] * (vel[:, :, None] * vel[:, None, :])
    if vel_cov is not None:
        out += s2[:, None, None] * vel_cov
    return out


def time_noise_soa(r: np.ndarray, vel: np.ndarray, vel_cov: np.ndarray | None,
                   sigma_t: np.ndarray) -> None:
    """`time_noise` in place, batch axis last: r (d, d, N), vel (d, N), vel_cov (d, d, N)
    or None, sigma_t (N,). Rows without time noise keep their R bit for bit."""
    s2 = np.square(np.nan_to_num(np.asarray(sigma_t, dtype=float), nan=0.0))
    d = r.shape[0]
    for a in range(d):
        for b in range(a, d):
            add = vel[a] * vel[b]
            if vel_cov is not None:
                add = add + vel_cov[a, b]
            r[a, b] += s2 * add
            if b != a:
                r[b, a] = r[a, b]


def stated(batch_sigma_t: np.ndarray | None) -> bool:
    """Whether a batch's time noise column has any row with time noise."""
    return batch_sigma_t is not None and bool(np.nan_to_num(batch_sigma_t, nan=0.0).any())
