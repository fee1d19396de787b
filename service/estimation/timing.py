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
added to the converted R of polar and Cartesian measurements alike.

Time errors are heavy-tailed (a position repeated under the next second's time, a late
packet): given the innovation nu = z - x^ and the predicted position's covariance, the
term is weighted by Huber's weight of the innovation along the track, w = max(1, |u' nu|
/ (k s)), u = v^ / |v^|, s^2 = u' (P_pos + R + T) u, k = `defaults.TIME_HUBER` (the
M-estimator as a Kalman update: Masreliez & Martin, IEEE TAC 22(3), 1977): a measurement
far along the track moves the track as one at k sigma would, and the across-track part
of it is used in full. Pure NumPy; `imm_kernel._time_noise` is the compiled twin.
"""

from __future__ import annotations

import numpy as np

from .. import defaults


def time_noise(r: np.ndarray, vel: np.ndarray, vel_cov: np.ndarray | None,
               sigma_t: np.ndarray, innovation: np.ndarray | None = None,
               pos_cov: np.ndarray | None = None, huber: float = defaults.TIME_HUBER
               ) -> np.ndarray:
    """R (N, d, d) plus w sigma_t^2 (v v' + P_vv) per row: vel (N, d) the predicted
    velocity, vel_cov (N, d, d) its covariance (None: taken as exact), sigma_t (N,) s
    (NaN or 0: no time noise, the row's R unchanged); w Huber's weight of the innovation
    (N, d) along the track with the predicted position's covariance pos_cov (N, d, d)
    (None: w = 1). A new array."""
    s2 = np.square(np.nan_to_num(np.asarray(sigma_t, dtype=float), nan=0.0))
    term = vel[:, :, None] * vel[:, None, :]
    if vel_cov is not None:
        term = term + vel_cov
    term *= s2[:, None, None]
    if innovation is not None and pos_cov is not None:
        speed = np.linalg.norm(vel, axis=1)
        u = vel / np.where(speed > 0, speed, 1.0)[:, None]
        s = np.einsum("na,nab,nb->n", u, pos_cov + r + term, u)
        e = np.abs(np.einsum("na,na->n", u, innovation))
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where((speed > 0) & (s > 0), e / (huber * np.sqrt(s)), 1.0)
        term *= np.maximum(np.nan_to_num(w, nan=1.0), 1.0)[:, None, None]
    return r + term


def time_noise_soa(r: np.ndarray, vel: np.ndarray, vel_cov: np.ndarray | None,
                   sigma_t: np.ndarray, innovation: np.ndarray | None = None,
                   pos_cov: np.ndarray | None = None, huber: float = defaults.TIME_HUBER
                   ) -> None:
    """`time_noise` in place, batch axis last: r (d, d, N), vel (d, N), vel_cov (d, d, N)
    or None, sigma_t (N,), innovation (d, N), pos_cov (d, d, N). Rows without time noise
    keep their R bit for bit."""
    got = time_noise(np.moveaxis(r, -1, 0), vel.T, _lead(vel_cov), sigma_t,
                     _lead(innovation), _lead(pos_cov), huber)
    some = np.nan_to_num(np.asarray(sigma_t, dtype=float), nan=0.0) > 0
    if some.all():
        r[...] = np.moveaxis(got, 0, -1)
    elif some.any():
        idx = np.flatnonzero(some)
        r[:, :, idx] = np.moveaxis(got[idx], 0, -1)


def _lead(a: np.ndarray | None) -> np.ndarray | None:
    """The batch axis (last) first."""
    return None if a is None else np.moveaxis(a, -1, 0)


def stated(batch_sigma_t: np.ndarray | None) -> bool:
    """Whether a batch's time noise column has any row with time noise."""
    return batch_sigma_t is not None and bool(np.nan_to_num(batch_sigma_t, nan=0.0).any())
