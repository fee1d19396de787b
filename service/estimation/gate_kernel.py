"""An unlabelled scan's gate compiled (Numba), apart so that importing `gate_jit` does
not import Numba: the conversion at the measured points (NumPy form
`ucm.cmkf_arrays(batch, None)`), the pairs' distances under the gate (NumPy form in
`tracking.gating.gate`) and the IMM's two-component pair likelihood (NumPy form in
`IMM.gate_prediction`). The same formulas, to rounding (tests/test_gate_jit.py); the
NumPy forms serve until this is loaded (`estimation.jit`)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

LOG_2PI = math.log(2.0 * math.pi)


@njit(cache=True, nogil=True)
def at_points(polar, values, sigmas, origin, z, r):  # pragma: no cover - compiled
    """Each row i converted into z[i] (d,) and R[i] (d, d): a polar one by the unbiased
    conversion (`polar.unbiased`) with the UCM covariance at the converted point
    (`polar.ucm_covariance`, Mo et al. 1998), a Cartesian one as given with
    R = diag(sigma^2)."""
    d = values.shape[1]
    for i in range(values.shape[0]):
        for a in range(d):
            for b in range(d):
                r[i, a, b] = 0.0
        if not polar[i]:
            for a in range(d):
                z[i, a] = values[i, a]
                r[i, a, a] = sigmas[i, a] ** 2
            continue
        rng, az, sr, saz = values[i, 0], values[i, 1], sigmas[i, 0], sigmas[i, 1]
        lb = math.exp(-0.5 * saz**2)
        lb4 = lb**4
        if d == 2:
            x, y = rng * math.sin(az) / lb, rng * math.cos(az) / lb
            z[i, 0], z[i, 1] = origin[i, 0] + x, origin[i, 1] + y
            rr = math.sqrt(x * x + y * y)  # the converted point in polar form
            az2 = math.atan2(x, y)
            p0, p1 = rr * math.sin(az2), rr * math.cos(az2)
            big_b = rr**2 + sr**2
            s2a, c2a = math.sin(2 * az2), math.cos(2 * az2)
            k = big_b / (2 * lb**2)
            r[i, 0, 0] = k * (1 - lb4 * c2a) - p0 * p0
            r[i, 1, 1] = k * (1 + lb4 * c2a) - p1 * p1
            r[i, 0, 1] = r[i, 1, 0] = k * lb4 * s2a - p0 * p1
            continue
        el, sel = values[i, 2], sigmas[i, 2]
        le = math.exp(-0.5 * sel**2)
        le4 = le**4
        ce = math.cos(el)
        x, y = rng * ce * math.sin(az) / (lb * le), rng * ce * math.cos(az) / (lb * le)
        h = rng * math.sin(el) / le
        z[i, 0], z[i, 1], z[i, 2] = origin[i, 0] + x, origin[i, 1] + y, origin[i, 2] + h
        rr = math.sqrt(x * x + y * y + h * h)
        az2 = math.atan2(x, y)
        el2 = math.atan2(h, math.hypot(x, y))
        ce2 = math.cos(el2)
        p0, p1, p2 = rr * ce2 * math.sin(az2), rr * ce2 * math.cos(az2), rr * math.sin(el2)
        big_b = rr**2 + sr**2
        s2a, c2a = math.sin(2 * az2), math.cos(2 * az2)
        c2e, s2e = math.cos(2 * el2), math.sin(2 * el2)
        k = big_b * (1 + le4 * c2e) / (4 * lb**2 * le**2)
        g = big_b / (2 * le**2)
        r[i, 0, 0] = k * (1 - lb4 * c2a) - p0 * p0
        r[i, 1, 1] = k * (1 + lb4 * c2a) - p1 * p1
        r[i, 0, 1] = r[i, 1, 0] = k * lb4 * s2a - p0 * p1
        r[i, 2, 2] = g * (1 - le4 * c2e) - p2 * p2
        r[i, 0, 2] = r[i, 2, 0] = g * le4 * s2e * math.sin(az2) - p0 * p2
        r[i, 1, 2] = r[i, 2, 1] = g * le4 * s2e * math.cos(az2) - p1 * p2


@njit(cache=True, nogil=True)
def _ldl(s, low, piv):  # pragma: no cover - compiled
    """S = L D L' of a symmetric (d, d) S (lower triangle read; Golub & Van Loan 2013,
    alg. 4.1.1, no pivoting: S is a covariance): L below its unit diagonal into low, D
    into piv; whether no pivot is zero."""
    d = s.shape[0]
    for j in range(d):
        pj = s[j, j]
        for q in range(j):
            pj -= low[j, q] ** 2 * piv[q]
        piv[j] = pj
        if pj == 0.0:
            return False
        for i in range(j + 1, d):
            v = s[i, j]
            for q in range(j):
                v -= low[i, q] * low[j, q] * piv[q]
            low[i, j] = v / pj
    return True


@njit(cache=True, nogil=True)
def _distance(s, nu, low, piv, y):  # pragma: no cover - compiled
    """(nu' S^-1 nu, det S) by `_ldl` and forward substitution (NaN and 0 for a zero
    pivot, as `linalg.ldl_inverse` flags a singular S)."""
    if not _ldl(s, low, piv):
        return np.nan, 0.0
    d2, det = 0.0, 1.0
    for i in range(len(nu)):
        v = nu[i]
        for q in range(i):
            v -= low[i, q] * y[q]
        y[i] = v
        d2 += v * v / piv[i]
        det *= piv[i]
    return d2, det


@njit(cache=True, nogil=True)
def gate_pairs(ti, dj, z, mean_s, cross_s, r, nu, d2, det):  # pragma: no cover - compiled
    """Each pair k of track ti[k] and detection dj[k]: the innovation nu[k] = z - mean,
    S = P_pos + R and the squared Mahalanobis distance d2[k] and det S (`gating.gate`'s
    pair stage; mean_s (d, T), cross_s (d, n, T) batch axis last)."""
    d = z.shape[1]
    s, low = np.zeros((d, d)), np.zeros((d, d))
    piv, y = np.empty(d), np.empty(d)
    for k in range(len(ti)):
        t, j = ti[k], dj[k]
        for a in range(d):
            nu[k, a] = z[j, a] - mean_s[a, t]
            for b in range(a + 1):
                s[a, b] = cross_s[a, b, t] + r[j, a, b]
        d2[k], det[k] = _distance(s, nu[k], low, piv, y)


@njit(cache=True, nogil=True)
def mixture(loglik, ti, nu, r, narrow, w, out):  # pragma: no cover - compiled
    """Each pair's log-likelihood under the IMM's two components (`IMM.gate_prediction`):
    (1 - w) N(nu; S_mix) + w N(nu; S_wide), with S_mix = narrow[ti] + r (r: the pairs'
    own R) and the widest mode's log-likelihood `loglik` given."""
    d = nu.shape[1]
    s, low = np.zeros((d, d)), np.zeros((d, d))
    piv, y = np.empty(d), np.empty(d)
    for k in range(len(ti)):
        t = ti[k]
        for a in range(d):
            for b in range(a + 1):
                s[a, b] = narrow[t, a, b] + r[k, a, b]
        d2, det = _distance(s, nu[k], low, piv, y)
        ll = -0.5 * (d2 + math.log(det) + d * LOG_2PI) if det > 0.0 else -np.inf
        a_, b_ = math.log1p(-w[t]) + ll, math.log(w[t]) + loglik[k]
        if a_ == b_:  # both -inf too
            out[k] = a_ + math.log(2.0)
        else:
            out[k] = max(a_, b_) + math.log1p(math.exp(-abs(a_ - b_)))
