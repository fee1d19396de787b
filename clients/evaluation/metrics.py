"""Accuracy and consistency yardsticks: posterior Cramér-Rao bound, NEES, chi2, RMSE.

Pure NumPy (plus the standard library); no Zenoh and no service imports. States are
[pos(d), vel(d)] with d = 3 (range, azimuth, elevation) or d = 2 (range, azimuth).
Azimuth is a compass bearing from North, clockwise: x = r cos(el) sin(az),
y = r cos(el) cos(az), z = r sin(el) (as in clients/feeds/scenarios.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from statistics import NormalDist

import numpy as np

InfoFn = Callable[[np.ndarray], np.ndarray]


# ---------------------------------------------------------------- models
def cv_model(d: int, T: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearly-constant-velocity F and Q for state [pos(d), vel(d)], piecewise-constant
    white acceleration of std q over each period T (x_{k+1} = F x_k + G a_k)."""
    # Bar-Shalom, Li & Kirubarajan, Estimation with Applications to Tracking (2001), 6.3.3
    eye = np.eye(d)
    F = np.block([[eye, T * eye], [np.zeros((d, d)), eye]])
    G = np.vstack([0.5 * T**2 * eye, T * eye])
    return F, q**2 * G @ G.T


# ---------------------------------------------------------------- polar measurement
def polar_jacobian(states: np.ndarray, elevation: bool = True) -> np.ndarray:
    """Jacobian of (r, az[, el]) w.r.t. the state [pos(d), vel(d)], for states (..., 2d).

    Returns (..., m, 2d) with m = 3 if elevation else 2 (d = m); velocity columns are 0."""
    s = np.asarray(states, dtype=float)
    d = 3 if elevation else 2
    x, y = s[..., 0], s[..., 1]
    rho2 = x**2 + y**2
    H = np.zeros(s.shape[:-1] + (d, 2 * d))
    if elevation:
        z = s[..., 2]
        r2 = rho2 + z**2
        r, rho = np.sqrt(r2), np.sqrt(rho2)
        H[..., 0, 0], H[..., 0, 1], H[..., 0, 2] = x / r, y / r, z / r
        H[..., 2, 0] = -x * z / (r2 * rho)
        H[..., 2, 1] = -y * z / (r2 * rho)
        H[..., 2, 2] = rho / r2
    else:
        r = np.sqrt(rho2)
        H[..., 0, 0], H[..., 0, 1] = x / r, y / r
    # az = atan2(x, y): d az/dx = y / rho^2, d az/dy = -x / rho^2
    H[..., 1, 0], H[..., 1, 1] = y / rho2, -x / rho2
    return H


def polar_info(sr: float, saz: float, sel: float | None) -> InfoFn:
    """info_fn for `pcrb`: E[H' R^-1 H] of a polar sensor at the origin, averaged over
    the given true states (runs, n); R = diag(sr^2, saz^2[, sel^2])."""
    sig = np.array([sr, saz] if sel is None else [sr, saz, sel], dtype=float)
    w = 1.0 / sig**2

    def info(states: np.ndarray) -> np.ndarray:
        H = polar_jacobian(states, elevation=sel is not None)
        return np.einsum("rmi,m,rmj->ij", H, w, H) / H.shape[0]

    return info


def linear_info(H: np.ndarray, R: np.ndarray) -> InfoFn:
    """info_fn for `pcrb`: H' R^-1 H of a linear measurement z = H x + v (state-free)."""
    J = H.T @ np.linalg.solve(R, H)
    J = 0.5 * (J + J.T)
    return lambda states: J


# ---------------------------------------------------------------- PCRB
def pcrb(truths: np.ndarray, F: np.ndarray, Q: np.ndarray, J0: np.ndarray,
         info_fn: InfoFn) -> np.ndarray:
    """Posterior Cramér-Rao bound sequence (K, n, n) = inv(J_k) for linear-Gaussian dynamics.

    J_{k+1} = (Q + F J_k^-1 F')^-1 + info_fn(truths[:, k+1]); truths (runs, K, n).
    J0 is the full information at scan 0 (prior and whatever scan 0 contributed); the
    measurement information is added from scan 1 on."""
    # Tichavsky, Muravchik & Nehorai, IEEE TSP 46(5) 1998, eq. (21)-(22), additive Gaussian noise
    # (also stonesoup/metricgenerator/pcrbmetric.py)
    truths = np.asarray(truths, dtype=float)
    K, n = truths.shape[1], truths.shape[2]
    out = np.empty((K, n, n))
    J = 0.5 * (J0 + J0.T)
    P = np.linalg.inv(J)
    out[0] = P
    for k in range(1, K):
        Pp = F @ P @ F.T + Q
        J = np.linalg.inv(0.5 * (Pp + Pp.T)) + info_fn(truths[:, k])
        P = np.linalg.inv(0.5 * (J + J.T))
        out[k] = P = 0.5 * (P + P.T)
    return out


def pcrb_polar(truths: np.ndarray, F: np.ndarray, Q: np.ndarray, J0: np.ndarray,
               sr: float, saz: float, sel: float | None) -> np.ndarray:
    """PCRB (K, n, n) for a polar sensor at the origin measuring (r, az[, el]).

    d = 3 with elevation (sel given), 2 without (sel None); see `pcrb`."""
    return pcrb(truths, F, Q, J0, polar_info(sr, saz, sel))


def j0_diffuse(truth0: np.ndarray, sr: float, saz: float, sel: float | None,
               sigma_v: float = 1e4) -> np.ndarray:
    """J0 for initiation from the scan-0 measurement alone: its expected polar information
    (position) plus a diffuse velocity prior of std sigma_v (m/s). truth0 (runs, n)."""
    J = polar_info(sr, saz, sel)(np.atleast_2d(truth0))
    d = J.shape[0] // 2
    J[d:, d:] += np.eye(d) / sigma_v**2
    return J


def j1_two_point(truth0: np.ndarray, truth1: np.ndarray, F: np.ndarray, sr: float,
                 saz: float, sel: float | None) -> np.ndarray:
    """Information at scan 1 of two-point differencing (scans 0 and 1, no process noise
    between them): J1 = F^-T I0 F^-1 + I1. Use it as J0 of `pcrb(truths[:, 1:], ...)`."""
    # Bar-Shalom, Li & Kirubarajan (2001), 5.5.3: two-point differencing initialisation
    info = polar_info(sr, saz, sel)
    Fi = np.linalg.inv(F)
    J = Fi.T @ info(np.atleast_2d(truth0)) @ Fi + info(np.atleast_2d(truth1))
    return 0.5 * (J + J.T)


def position_bound(bounds: np.ndarray, d: int) -> np.ndarray:
    """sqrt(trace) of the position block of bound covariances (K, n, n) -> (K,)."""
    return np.sqrt(np.trace(bounds[..., :d, :d], axis1=-2, axis2=-1))


def velocity_bound(bounds: np.ndarray, d: int) -> np.ndarray:
    """sqrt(trace) of the velocity block of bound covariances (K, n, n) -> (K,)."""
    return np.sqrt(np.trace(bounds[..., d:2 * d, d:2 * d], axis1=-2, axis2=-1))


# ---------------------------------------------------------------- consistency
def nees(err: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared e' P^-1 e; err (..., n), P (..., n, n) -> (...)."""
    err = np.asarray(err, dtype=float)
    sol = np.linalg.solve(P, err[..., None])[..., 0]
    return np.einsum("...i,...i->...", err, sol)


def _gammainc_lower(a: float, x: float) -> float:
    """Regularised lower incomplete gamma P(a, x)."""
    # Numerical Recipes (3rd ed.) 6.2: series for x < a + 1, Lentz continued fraction otherwise
    if x <= 0.0:
        return 0.0
    lead = math.exp(-x + a * math.log(x) - math.lgamma(a))
    if x < a + 1.0:
        term = total = 1.0 / a
        ap = a
        for _ in range(100_000):
            ap += 1.0
            term *= x / ap
            total += term
            if abs(term) < abs(total) * 1e-15:
                break
        return min(1.0, total * lead)
    tiny = 1e-300
    b = x + 1.0 - a
    c, dd = 1.0 / tiny, 1.0 / b
    h = dd
    for i in range(1, 100_000):
        an = -i * (i - a)
        b += 2.0
        dd = an * dd + b
        dd = tiny if abs(dd) < tiny else dd
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        dd = 1.0 / dd
        delta = dd * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return max(0.0, 1.0 - lead * h)


def chi2_cdf(x: float, dof: float) -> float:
    """Chi-square cumulative distribution function."""
    return _gammainc_lower(0.5 * dof, 0.5 * x)


def chi2_ppf_wh(prob: float, dof: float) -> float:
    """Chi-square quantile by the Wilson-Hilferty cube-root normal approximation."""
    # Wilson & Hilferty, PNAS 17(12) 1931
    z = NormalDist().inv_cdf(prob)
    c = 2.0 / (9.0 * dof)
    return dof * max(1.0 - c + z * math.sqrt(c), 0.0) ** 3


def chi2_ppf(prob: float, dof: float) -> float:
    """Chi-square quantile: bisection of `chi2_cdf` (exact to ~1e-10 relative)."""
    if not 0.0 < prob < 1.0:
        raise ValueError("prob must lie in (0, 1)")
    lo, hi = 0.0, max(1.0, 2.0 * chi2_ppf_wh(prob, dof))
    while chi2_cdf(hi, dof) < prob:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi2_cdf(mid, dof) < prob:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    return 0.5 * (lo + hi)


def chi2_interval(dof: int, runs: int, p: float = 0.95) -> tuple[float, float]:
    """Two-sided probability-p interval of the AVERAGE of `runs` independent chi2(dof)
    variables (runs x average ~ chi2(runs dof)), e.g. for the average NEES or NIS."""
    # Bar-Shalom, Li & Kirubarajan (2001), 5.4.2: N * average NEES ~ chi2(N n)
    k = dof * runs
    return chi2_ppf(0.5 * (1.0 - p), k) / runs, chi2_ppf(0.5 * (1.0 + p), k) / runs


# ---------------------------------------------------------------- RMSE
def rmse_windows(sq_err: np.ndarray, edges: Sequence) -> list[float]:
    """RMSE = sqrt(mean over runs and scans) of squared errors sq_err (runs, K) in scan
    windows. edges: boundaries [e0, e1, ...] giving windows [e0, e1), [e1, e2), ... or
    explicit (start, stop) pairs. NaN entries (no track) are ignored."""
    sq = np.asarray(sq_err, dtype=float)
    if sq.ndim == 1:
        sq = sq[None, :]
    edges = list(edges)
    if edges and isinstance(edges[0], Sequence | np.ndarray):
        windows = [(int(a), int(b)) for a, b in edges]
    else:
        windows = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    return [float(np.sqrt(np.nanmean(sq[:, a:b]))) for a, b in windows]


# ---------------------------------------------------------------- scenario B
def scenario_b_truths(runs: int, seed: int) -> np.ndarray:
    """Truth states (runs, scans, 6) of scenario B, from
    zenoh_track.clients.feeds.scenarios.radar3d."""
    from zenoh_track.clients.feeds.scenarios import radar3d  # numpy-only module

    scans = [np.array([tr["pos"] + tr["vel"] for _, tr in truth])
             for _, _, truth in radar3d(runs=runs, seed=seed)]
    return np.stack(scans, axis=1)


def scenario_b_bound(runs: int, seed: int, init: str = "diffuse",
                     sigma_v: float = 1e4) -> tuple[np.ndarray, np.ndarray]:
    """Per-scan PCRB on position and velocity RMSE (sqrt trace) for scenario B, scans 0..199.

    init "diffuse": J0 = information of the scan-0 measurement plus a diffuse velocity
    prior (std sigma_v); at scan 1 this is the information of the first two measurements,
    i.e. the bound of two-point differencing with the process noise between them kept.
    init "two-point": J1 of `j1_two_point` at scan 1; scan 0 then has the position bound of
    the first measurement alone and an infinite velocity bound."""
    from zenoh_track.clients.feeds.scenarios import RadarB

    cfg = RadarB()
    truths = scenario_b_truths(runs, seed)
    F, Q = cv_model(3, cfg.period, cfg.q)
    sr, sa = cfg.sr, cfg.sa
    if init == "diffuse":
        bounds = pcrb_polar(truths, F, Q, j0_diffuse(truths[:, 0], sr, sa, sa, sigma_v),
                            sr, sa, sa)
        return position_bound(bounds, 3), velocity_bound(bounds, 3)
    if init == "two-point":
        J1 = j1_two_point(truths[:, 0], truths[:, 1], F, sr, sa, sa)
        bounds = pcrb_polar(truths[:, 1:], F, Q, J1, sr, sa, sa)
        I0 = polar_info(sr, sa, sa)(truths[:, 0])
        p0 = math.sqrt(np.trace(np.linalg.inv(I0[:3, :3])))
        return (np.concatenate([[p0], position_bound(bounds, 3)]),
                np.concatenate([[math.inf], velocity_bound(bounds, 3)]))
    raise ValueError(f"unknown init {init!r}")
