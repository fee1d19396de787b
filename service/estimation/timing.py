"""The noise of a measurement's time: a position stamped with a time that is not quite
its own is a position of the track a little earlier or later.

A measurement z stamped t but taken at t + e (e the time error, zero mean, variance
sigma_t^2, independent of the position noise) is, to first order, the position at t plus
v e, v the target's velocity: z = p(t) + v e + w, so its error covariance is
R + sigma_t^2 v v' (the time error projected along the path; Choi, Choi, Park & Chung,
"State estimation with delayed measurements considering uncertainty of time delay",
IEEE ICRA 2009; docs/timing.md). The velocity is known only as the prediction's,
N(v^, P_vv): averaged over it (as the converted measurement's R is averaged over the
predicted position, `ucm.ucm_expected_soa`) the term is T = sigma_t^2 (v^ v^' + P_vv)
(`time_term`). A radar measurement's time error moves its converted point the same way,
so the term is added to the converted R of polar and Cartesian measurements alike.

Time errors are heavy-tailed (a position repeated under the next second's time, a late
packet): e is a Student t with 3 degrees of freedom and variance sigma_t^2, written as
the three-Gaussian scale mixture closest to it (Kullback-Leibler; `defaults.TIME_MIXTURE`:
70 % of measurements at 0.53 sigma_t, 28 % at 1.3 sigma_t, 1 in 75 at 5 sigma_t), so a
measurement's covariance is R + s_c T with probability pi_c. The update is the exact Bayesian one of
that mixture, a Gaussian sum (Sorenson & Alspach, "Recursive Bayesian estimation using
Gaussian sums", Automatica 7, 1971), reduced to one Gaussian by its moments, as the IMM
reduces its modes (`mixture_update`); its likelihood is the mixture's, so that the
IMM's modes read a late position as the tail of the time's noise, not as a manoeuvre
(the contaminated-normal world of Masreliez & Martin, IEEE TAC 22(3), 1977, updated
exactly rather than by their minimax score). Pure NumPy; `imm_kernel._time_term` and
`imm_kernel._components` are the compiled twins.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .. import defaults

# (x (N, n), P (N, n, n), z (N, m), R (N, m, m)) -> x, P, NIS, finite, log-likelihood
Update = Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def time_term(vel: np.ndarray, vel_cov: np.ndarray | None, sigma_t: np.ndarray
              ) -> np.ndarray:
    """T = sigma_t^2 (v v' + P_vv) per row (N, d, d): vel (N, d) the predicted velocity,
    vel_cov (N, d, d) its covariance (None: taken as exact), sigma_t (N,) s (NaN or 0: no
    time noise, T zero)."""
    s2 = np.square(np.nan_to_num(np.asarray(sigma_t, dtype=float), nan=0.0))
    term = vel[:, :, None] * vel[:, None, :]
    if vel_cov is not None:
        term = term + vel_cov
    term *= s2[:, None, None]
    return term


def time_noise(r: np.ndarray, vel: np.ndarray, vel_cov: np.ndarray | None,
               sigma_t: np.ndarray) -> np.ndarray:
    """R + T per row: the covariance of the measurement's noise, the time's included (the
    variance of the mixture; a filter that takes one Gaussian takes this). A new array."""
    return r + time_term(vel, vel_cov, sigma_t)


def mixture_update(update: Update, x: np.ndarray, p: np.ndarray, z: np.ndarray,
                   r: np.ndarray, term: np.ndarray, some: np.ndarray,
                   mixture: tuple[tuple[float, float], ...] = defaults.TIME_MIXTURE
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The update of rows x (N, n), P (N, n, n) by z (N, m) whose noise is R + s_c T with
    probability pi_c (`mixture`: (pi_c, s_c) per component; T = `term` (N, m, m)), by
    `update` (`kalman.update_full`'s signature), each component's posterior weighed by
    pi_c times its likelihood and the sum reduced to its mean and covariance. Returns x,
    P, the mask of finite rows and the log-likelihood of the mixture. Rows not in `some`
    (N,) bool (no time noise) take the first component alone: their plain update, bit
    for bit (T is zero there)."""
    (pi0, s0), *rest = mixture
    xs, ps, _, ok, ll = update(x, p, z, r + s0 * term)
    xn, pn, lik = xs.copy(), ps.copy(), ll.copy()
    if not some.any():
        return xn, pn, ok, lik
    parts = [(xs[some], ps[some], ll[some] + np.log(pi0))]
    for pi, s in rest:
        xc, pc, _, okc, llc = update(x[some], p[some], z[some], r[some] + s * term[some])
        ok[some] &= okc
        parts.append((xc, pc, llc + np.log(pi)))
    logs = np.stack([lc for _, _, lc in parts], 1)  # (k, C)
    top = logs.max(1, keepdims=True)
    with np.errstate(invalid="ignore"):  # a row with no finite component: masked by ok
        w = np.exp(logs - top)
        total = w.sum(1, keepdims=True)
        w /= total
    mean = np.zeros_like(parts[0][0])
    for c, (xc, _, _) in enumerate(parts):
        mean += w[:, c, None] * xc
    cov = np.zeros_like(parts[0][1])
    for c, (xc, pc, _) in enumerate(parts):
        dev = xc - mean
        cov += w[:, c, None, None] * (pc + dev[:, :, None] * dev[:, None, :])
    xn[some], pn[some] = mean, 0.5 * (cov + cov.transpose(0, 2, 1))
    lik[some] = (top + np.log(total))[:, 0]
    ok[some] &= np.isfinite(lik[some])
    return xn, pn, ok, lik


def timed(batch_sigma_t: np.ndarray | None) -> np.ndarray | None:
    """The rows of a batch's time noise column with time noise (N,) bool; None when none
    has any."""
    if batch_sigma_t is None:
        return None
    some = np.nan_to_num(batch_sigma_t, nan=0.0) > 0
    return some if some.any() else None


def stated(batch_sigma_t: np.ndarray | None) -> bool:
    """Whether a batch's time noise column has any row with time noise."""
    return timed(batch_sigma_t) is not None
