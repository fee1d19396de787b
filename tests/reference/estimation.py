"""Textbook forms of the fast batch-last kernels, a row at a time on ordinary row-major
arrays (x (N, n), P (N, n, n)) with plain NumPy, written to be read next to the
equations (in the style of FilterPy or Stone Soup). Slow; `tests/test_reference.py`
checks every kernel against its form here. Not more accurate than the kernels: the
textbook UCM covariance E[z z'] - p p' cancels terms of order r^2 and is rounded to a few
eps r^2 m^2, which the kernels' regrouped sums avoid.
"""

from __future__ import annotations

import math

import numpy as np

from zenoh_track.estimation.kalman import S_FLOOR
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.estimation.polar import cartesian_to_polar, ucm_covariance_polar, unbiased
from zenoh_track.estimation.ucm import ROUNDING


def motion_matrices(dt: np.ndarray, order: int, dim: int, q: float | np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """F and Q (N, n, n) of the `models` kinematic state, n = order * dim: per axis
    Phi[i, j] = T^(j-i) / (j-i)! and the continuous white noise of derivative `order`, of
    spectral density q^2 |T|, integrated over the step:
    Q_axis = q^2 |T| int_0^|T| phi(s) phi(s)' ds
    with phi(s) = [s^(order-1) / (order-1)!, ..., s, 1] (for order 2 the CWNA model of
    Bar-Shalom, Li & Kirubarajan 2001, sec. 6.2.2; for order 3 the white-jerk model of
    sec. 6.2.3), then F = kron(Phi, I_dim), Q = kron(Q_axis, I_dim). Reference of
    `models.transition` and `models.process_noise`."""
    dt = np.asarray(dt, dtype=float)
    qs = np.broadcast_to(np.asarray(q, dtype=float), dt.shape)
    f, qm = [], []
    for t, qi in zip(dt, qs, strict=True):
        phi = np.array([[t ** (j - i) / math.factorial(j - i) if j >= i else 0.0
                         for j in range(order)] for i in range(order)])
        # the integral term by term: s^(o-1-i) s^(o-1-j) integrates to |T|^k / k
        q_axis = abs(t) * np.array([[abs(t) ** (2 * order - 1 - i - j)
                            / (math.factorial(order - 1 - i) * math.factorial(order - 1 - j)
                               * (2 * order - 1 - i - j)) for j in range(order)]
                           for i in range(order)])
        f.append(np.kron(phi, np.eye(dim)))
        qm.append(np.kron(qi**2 * q_axis, np.eye(dim)))
    return np.array(f), np.array(qm)


def predict(x: np.ndarray, p: np.ndarray, f: np.ndarray, q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Kalman prediction x <- F x, P <- F P F' + Q of every row (Bar-Shalom, Li &
    Kirubarajan 2001, sec. 5.2.3-5.2.4). Reference of `models.predict_soa` (through
    `models.predict`) with F, Q from `motion_matrices`."""
    xp = np.array([fi @ xi for fi, xi in zip(f, x, strict=True)])
    pp = np.array([fi @ pi @ fi.T + qi for fi, pi, qi in zip(f, p, q, strict=True)])
    return xp, pp


def ucm_covariance_expected(mean: np.ndarray, cov: np.ndarray, sr: np.ndarray,
                            saz: np.ndarray, sel: np.ndarray | None,
                            az_meas: np.ndarray) -> np.ndarray:
    """UCM error covariance (N, d, d) (Mo et al., IEEE TAES 34(3), 1998:
    `polar.ucm_covariance_polar`) averaged over the prediction N(mean, cov)
    (sensor-relative) by the third-degree spherical cubature rule of Arasaratnam & Haykin
    (IEEE TAC 54(6), 2009): the mean over the 2d points mean +- sqrt(d) s_k, s_k the columns
    of the symmetric square root S = V diag(sqrt(lambda)) V' of cov (unique where
    eigenvalues repeat, unlike V; eigenvalues below ROUNDING x the largest taken as zero),
    each evaluated at the point's range and elevation and at its azimuth moved toward the
    measured one by w = var_az / (var_az + saz^2), the azimuth difference wrapped to [-pi,
    pi]. var_az is the predicted variance along the tangent (y, -x) / rho at the mean over
    rho^2 = x^2 + y^2 (floored at 1e-12 m^2); at rho = 0 the tangent variance is the mean
    horizontal variance (c_xx + c_yy) / 2. A row whose cov is not finite gets NaN. Reference
    of `ucm.ucm_expected_soa`."""
    n, d = mean.shape
    out = np.full((n, d, d), np.nan)
    for i in range(n):
        if not np.isfinite(cov[i]).all():
            continue
        lam, v = np.linalg.eigh(cov[i])
        lam = np.where(lam > ROUNDING * lam.max(), lam, 0.0)  # rounding of a zero: zero
        root = (v * np.sqrt(d * lam)) @ v.T  # sqrt(d) x the symmetric square root
        pts = np.concatenate([mean[i] + root, mean[i] - root])
        x, y = mean[i, 0], mean[i, 1]
        rho2 = x * x + y * y
        tangent = np.array([y, -x])
        if rho2 > 0:
            var_t = tangent @ cov[i, :2, :2] @ tangent / rho2
        else:
            var_t = 0.5 * (cov[i, 0, 0] + cov[i, 1, 1])
        var_az = var_t / max(rho2, 1e-12)
        w = var_az / (var_az + saz[i] ** 2)
        r, az, el = cartesian_to_polar(pts)
        az = az + w * np.angle(np.exp(1j * (az_meas[i] - az)))
        k = np.ones(2 * d)
        rk = ucm_covariance_polar(r, az, el, sr[i] * k, saz[i] * k,
                                  None if sel is None else sel[i] * k)
        out[i] = rk.mean(0)
    return out


def cmkf_convert(batch: MeasurementBatch, pos: np.ndarray, cov: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Converted measurements z (N, d) and R (N, d, d) for targets predicted at
    N(pos, cov) (common frame): a polar one is the sensor origin plus the UCM point
    (`polar.unbiased`, Mo et al. 1998) with R = `ucm_covariance_expected` at the
    sensor-relative prediction; a Cartesian one is as given with R = diag(sigma^2).
    Reference of `ucm.cmkf_soa`."""
    d = batch.dim
    z, r = np.empty((len(batch), d)), np.empty((len(batch), d, d))
    for i in range(len(batch)):
        val, sig, origin = batch.values[i], batch.sigmas[i], batch.origin[i, :d]
        if not batch.polar[i]:
            z[i], r[i] = val, np.diag(sig**2)
            continue
        el, sel = (val[2:], sig[2:]) if d == 3 else (None, None)
        z[i] = origin + unbiased(val[:1], val[1:2], el, sig[1:2], sel)[0]
        r[i] = ucm_covariance_expected((pos[i] - origin)[None], cov[i][None], sig[:1],
                                       sig[1:2], sel, val[1:2])[0]
    return z, r


def joseph_update(x: np.ndarray, p: np.ndarray, z: np.ndarray, r: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Kalman update with H = [I 0] (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.2.3):
    nu = z - H x, S = H P H' + R (+ S_FLOOR I), K = P H' S^-1, x + K nu and the Joseph
    form (I - KH) P (I - KH)' + K R K' (eq. 5.2.3-18); returns x, P, the NIS nu' S^-1 nu
    and det S. Reference of `kalman.update_soa` (through `kalman.update_full`)."""
    n_rows, n = x.shape
    m = z.shape[1]
    h = np.hstack([np.eye(m), np.zeros((m, n - m))])
    xn, pn = np.empty((n_rows, n)), np.empty((n_rows, n, n))
    nis, det = np.empty(n_rows), np.empty(n_rows)
    for i in range(n_rows):
        nu = z[i] - h @ x[i]
        s = h @ p[i] @ h.T + r[i] + S_FLOOR * np.eye(m)
        k = p[i] @ h.T @ np.linalg.inv(s)
        ikh = np.eye(n) - k @ h
        xn[i] = x[i] + k @ nu
        pn[i] = ikh @ p[i] @ ikh.T + k @ r[i] @ k.T
        nis[i] = nu @ np.linalg.solve(s, nu)
        det[i] = np.linalg.det(s)
    return xn, pn, nis, det


def cmkf_step(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
              q: float | np.ndarray, batch: MeasurementBatch
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One CMKF cycle: `predict` by `motion_matrices`, `cmkf_convert` at the prediction,
    `joseph_update`. Returns x, P and NIS. Reference of `filters.cmkf_step`."""
    f, qm = motion_matrices(np.broadcast_to(dt, len(x)), order, dim, q)
    xp, pp = predict(x, p, f, qm)
    z, r = cmkf_convert(batch, xp[:, :dim], pp[:, :dim, :dim])
    return joseph_update(xp, pp, z, r)[:3]


def eigh(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric Schur decomposition cov = V diag(lambda) V' of every row (Golub & Van
    Loan 2013, sec. 8.1): eigenvalues (N, d) ascending and unit eigenvectors as the
    columns of V (N, d, d), by LAPACK. Reference of `linalg.eigh` (which returns the
    pairs in another order and with other signs)."""
    return np.linalg.eigh(cov)


def ldl_solve(s: np.ndarray, b: np.ndarray, floor: float = 0.0
              ) -> tuple[np.ndarray, np.ndarray]:
    """(S + floor I)^-1 b and det(S + floor I) for S (N, m, m), b (N, m, k), by LU with
    partial pivoting. Reference of `linalg.ldl_solve` (S = L D L', Golub & Van Loan
    2013, alg. 4.1.1, then substitution; batch-last, in place)."""
    s = s + floor * np.eye(s.shape[-1])
    return np.linalg.solve(s, b), np.linalg.det(s)


def ldl_inverse(s: np.ndarray, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(S + floor I)^-1 and det(S + floor I) for S (N, m, m). Reference of
    `linalg.ldl_inverse` (S^-1 = L^-T D^-1 L^-1 from S = L D L', Golub & Van Loan 2013,
    alg. 4.1.1; batch-last, in place)."""
    s = s + floor * np.eye(s.shape[-1])
    return np.linalg.inv(s), np.linalg.det(s)

