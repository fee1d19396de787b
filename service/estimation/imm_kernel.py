"""The compiled kernels of the default IMM's update (Numba), for blocks of B rows with the
batch axis last (the innermost loop of every stage runs over the block, which the
compiler vectorises): mixing, prediction, the CMKF's converted measurement with R
averaged over each mode's prediction, the Joseph update, the mode probabilities and the
moments. `imm_jit` drives them; `IMM.update`'s own code and `ucm.cmkf_soa` are their
references (tests/test_imm_jit.py). One file on purpose: Numba's cache (`cache=True`,
beside this file or in the user's cache directory) is invalidated by the source file of
the function compiled, not by those of the functions it calls.

Formulas: Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan 2001, sec. 11.6.6 (the
IMM); Granstrom, Willett & Bar-Shalom, IEEE TAES 51(4), 2015 (mixing a CV mode into a
CA one); Mo et al., IEEE TAES 34(3), 1998 (the unbiased conversion); the averaging over
the prediction and its reasons are in `ucm.ucm_expected_soa`, the Joseph form's in
`kalman.update_soa`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import defaults
from .kalman import S_FLOOR
from .turn import TURN_SMALL
from .ucm import ROUNDING

LOG_2PI = math.log(2.0 * math.pi)
# reassociation and contraction (fused multiply-adds), not the flags that assume no NaN
# or infinity: the finiteness checks must hold
FAST = {"contract", "reassoc", "arcp", "nsz"}
JIT = {"cache": True, "nogil": True, "error_model": "numpy", "fastmath": FAST}
SWEEPS = 30  # Jacobi sweeps at most (a 3 x 3 converges to rounding in about 4)
# the constants of a measurement's noise that `noise` reads, rows of `point`'s `const`
SM, CM, SR2, SAZ2, SINH_A, SINH_E, E_AZ, E_EL, G0, G1, C0, C1, C2 = range(13)
CONSTS = 13
_FACT = np.array([1, 1, 2, 6])  # k! for the process noise's denominators
BLOCK, SMALL = defaults.IMM_BLOCK, defaults.IMM_SMALL  # `update_rows`, `update_few`



@njit(**JIT)
def update_rows(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, shared, polar,
                values, sigmas, origin, sigma_t, mixture, xn, pn, nis, ok):  # pragma: no cover
    """The update of every row, `BLOCK` rows at a time (the last block padded with copies of
    its last row, which are not written back). `shared`: one R for every mode, averaged
    over the mixture of the modes' predictions; else each mode's own. `sigma_t` (N,): each
    measurement's time noise, s (0 or NaN: none), `mixture` (C, 2) its components'
    probabilities and variance scales (`timing.mixture_update`)."""
    _rows(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, shared, BLOCK, polar,
          values, sigmas, origin, sigma_t, mixture, xn, pn, nis, ok)


@njit(**JIT)
def update_few(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, shared, polar,
               values, sigmas, origin, sigma_t, mixture, xn, pn, nis, ok):  # pragma: no cover
    """`update_rows` `SMALL` rows at a time: less padding for a pass of few rows."""
    _rows(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, shared, SMALL, polar,
          values, sigmas, origin, sigma_t, mixture, xn, pn, nis, ok)


@njit(**JIT, inline="always")
def _rows(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, shared, b, polar,
          values, sigmas, origin, sigma_t, mixture, xn, pn, nis, ok):  # pragma: no cover - compiled
    """The body of both, inlined so that the block length b is a constant of each."""
    m, n = mode_x.shape[1], mode_x.shape[2]
    d = n // 3
    mx, mp, mu = np.empty((m, n, b)), np.empty((m, n, n, b)), np.empty((m, b))
    h, pol, st2 = np.empty(b), np.empty(b, np.bool_), np.empty(b)
    val, sig, org = np.empty((d, b)), np.empty((d, b)), np.empty((3, b))
    w, c, z = np.empty((m, m, b)), np.empty((m, b)), np.empty((d, b))
    xp, pp = np.empty((m, n, b)), np.empty((m, n, n, b))  # each mode's prediction
    xu, pu = np.empty((m, n, b)), np.empty((m, n, n, b))  # ... and posterior
    rr, lik, fin = np.empty((m, d, d, b)), np.empty((m, b)), np.empty((m, b), np.bool_)
    xo, po, nb = np.empty((n, b)), np.empty((n, n, b)), np.empty(b)
    mean, spread = np.empty((n, b)), np.empty((n, n, b))  # of the mixture's prediction
    # the time's noise T per mode, a component's R, its posterior and log-weight
    tt, rc, lw = np.empty((m, d, d, b)), np.empty((d, d, b)), np.empty(b)
    xc, pc, lc, fc = np.empty((n, b)), np.empty((n, n, b)), np.empty(b), np.empty(b, np.bool_)
    # work arrays of the stages: (n, n) and (3, 3) matrices, vectors of 3, per row
    wk, w33, wv = np.empty((3, n, n, b)), np.empty((3, 3, 3, b)), np.empty((6, 3, b))
    dv, tv, tc = np.empty((n, b)), np.empty((4, n, b)), np.empty((TURN_COEFFS, b))
    const, mats, nvec = np.empty((CONSTS, b)), np.empty((3, 3, 3, b)), np.empty((13, 6, b))
    for lo in range(0, len(rows), b):
        _gather(mode_x, mode_p, mode_prob, rows, dt, lo, kinds, mx, mp, mu, h)
        for q in range(b):  # the block's measurements, batch axis last
            i = min(lo + q, len(rows) - 1)
            pol[q] = polar[i]
            st = sigma_t[i]
            st2[q] = st * st if st > 0.0 else 0.0  # NaN: none
            for a in range(d):
                val[a, q], sig[a, q] = values[a, i], sigmas[a, i]
            for a in range(3):
                org[a, q] = origin[a, i]
        point(pol, val, sig, org, d, z, const)
        _mixed_predictions(mx, mp, mu, h, tau, dest, kinds, qs, ws, w, c, xp, pp, wk, wv, dv,
                           tv, tc)
        # the mixture's prediction: its position, and its velocity for the time noise
        timed = st2.max() > 0.0
        _moments(xp, pp, c, 2 * d if timed else d, mean, spread, dv)
        if shared:
            noise(pol, sig, org, const, mean, spread, d, rr[0], mats, nvec)
            if timed:
                _time_term(mean, spread, d, st2, tt[0])
        for j in range(m):
            if not shared:
                noise(pol, sig, org, const, xp[j], pp[j], d, rr[j], mats, nvec)
                if timed:
                    _time_term(xp[j], pp[j], d, st2, tt[j])
            elif j:
                rr[j] = rr[0]
                tt[j] = tt[0]
            s = n if _accelerating(kinds[j]) else 2 * d
            if not timed:
                _update(xp[j], pp[j], s, d, z, rr[j], xu[j], pu[j], lik[j], fin[j], wk, w33,
                        wv)
                continue
            # the time's noise a mixture: each component's update, merged by moments
            _component(rr[j], tt[j], mixture[0, 1], rc)
            _update(xp[j], pp[j], s, d, z, rc, xu[j], pu[j], lik[j], fin[j], wk, w33, wv)
            for q in range(b):
                lw[q] = lik[j, q] + math.log(mixture[0, 0])
            for k in range(1, mixture.shape[0]):
                _component(rr[j], tt[j], mixture[k, 1], rc)
                _update(xp[j], pp[j], s, d, z, rc, xc, pc, lc, fc, wk, w33, wv)
                for q in range(b):
                    lc[q] += math.log(mixture[k, 0])
                _merge(xu[j], pu[j], lw, fin[j], xc, pc, lc, fc, st2, n, dv)
            for q in range(b):
                if st2[q] > 0.0:
                    lik[j, q] = lw[q]
        if timed:  # the NIS's R: the mixture's variance, R + T
            for j in range(m):
                for a in range(d):
                    for e in range(d):
                        for q in range(b):
                            rr[j, a, e, q] += tt[j, a, e, q]
        _probabilities(c, lik, fin, mu, nb)
        _moments(xu, pu, mu, n, xo, po, dv)
        _mixture_nis(mean, spread, rr, c, z, d, nis, lo, len(rows), w33, wv)
        for q in range(min(b, len(rows) - lo)):  # scatter
            i, row = lo + q, rows[lo + q]
            ok[i] = nb[q] == 1.0
            for a in range(n):
                xn[i, a] = xo[a, q]
                for e in range(n):
                    pn[i, a, e] = po[a, e, q]
            if ok[i]:
                for j in range(m):
                    mode_prob[row, j] = mu[j, q]
                    for a in range(n):
                        mode_x[row, j, a] = xu[j, a, q]
                        for e in range(n):
                            mode_p[row, j, a, e] = pu[j, a, e, q]


@njit(**JIT)
def predict_rows(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, c_out, x_out,
                 p_out):  # pragma: no cover - compiled
    """`IMM.predicted` of every row, `BLOCK` rows at a time: the predicted mode
    probabilities c_out (N, M) and each mode's prediction from its mixed initial condition
    x_out (N, M, n), p_out (N, M, n, n); a mode without acceleration holds it at zero (the
    padding of `models.motion`). The track store is not written."""
    _predicted(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, BLOCK, c_out,
               x_out, p_out)


@njit(**JIT)
def predict_few(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, c_out, x_out,
                p_out):  # pragma: no cover - compiled
    """`predict_rows` `SMALL` rows at a time."""
    _predicted(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, SMALL, c_out,
               x_out, p_out)


@njit(**JIT, inline="always")
def _predicted(mode_x, mode_p, mode_prob, rows, dt, tau, dest, kinds, qs, ws, b, c_out, x_out,
               p_out):  # pragma: no cover - compiled
    """The body of both (`_rows`' gather, mixing and prediction)."""
    m, n = mode_x.shape[1], mode_x.shape[2]
    d = n // 3
    mx, mp, mu = np.empty((m, n, b)), np.empty((m, n, n, b)), np.empty((m, b))
    h, w, c = np.empty(b), np.empty((m, m, b)), np.empty((m, b))
    xp, pp = np.empty((m, n, b)), np.empty((m, n, n, b))
    wk, wv = np.empty((3, n, n, b)), np.empty((6, 3, b))
    dv, tv, tc = np.empty((n, b)), np.empty((4, n, b)), np.empty((TURN_COEFFS, b))
    for lo in range(0, len(rows), b):
        _gather(mode_x, mode_p, mode_prob, rows, dt, lo, kinds, mx, mp, mu, h)
        _mixed_predictions(mx, mp, mu, h, tau, dest, kinds, qs, ws, w, c, xp, pp, wk, wv, dv,
                           tv, tc)
        for q in range(min(b, len(rows) - lo)):  # scatter
            i = lo + q
            for j in range(m):
                s = n if _accelerating(kinds[j]) else 2 * d
                c_out[i, j] = c[j, q]
                for a in range(n):
                    x_out[i, j, a] = xp[j, a, q] if a < s else 0.0
                    for e in range(n):
                        p_out[i, j, a, e] = pp[j, a, e, q] if a < s and e < s else 0.0


@njit(**JIT)
def gate_moments(c, xs, ps, d, mean, cross, narrow, c_wide):  # pragma: no cover - compiled
    """`IMM.gate_moments` from the predictions `predict_rows` made (c (N, M), xs (N, M, n),
    ps (N, M, n, n)): the mixture's position mean (N, d) and covariance (N, d, d), the
    widest mode's (largest position variance) position rows of the second moment about
    that mean (N, d, n) and its probability (N,)."""
    k, m, n = xs.shape
    mu = np.empty(n)
    for i in range(k):
        wide, most = 0, -np.inf
        for a in range(n):
            mu[a] = 0.0
        for j in range(m):
            tr = 0.0
            for a in range(d):
                tr += ps[i, j, a, a]
            if tr > most:
                wide, most = j, tr
            for a in range(n):
                mu[a] += c[i, j] * xs[i, j, a]
        for a in range(d):
            mean[i, a] = mu[a]
            for e in range(a, d):
                acc = 0.0
                for j in range(m):
                    acc += c[i, j] * (ps[i, j, a, e] + (xs[i, j, a] - mu[a])
                                      * (xs[i, j, e] - mu[e]))
                narrow[i, a, e] = acc
                narrow[i, e, a] = acc
            for e in range(n):
                cross[i, a, e] = ps[i, wide, a, e] + (xs[i, wide, a] - mu[a]) \
                    * (xs[i, wide, e] - mu[e])
        c_wide[i] = c[i, wide]


@njit(**JIT, inline="always")
def _gather(mode_x, mode_p, mode_prob, rows, dt, lo, kinds, mx, mp, mu, h):  # pragma: no cover
    """The block of rows lo.. (the last one repeated as padding) from the store into the
    batch-last work arrays: each mode's x and the upper triangle of its P (what `_mix`
    reads: a mode without acceleration, its position and velocity only; the rest of the
    work arrays is left unset), the mode probabilities and the dt: a third of the
    store's entries read (at 100,000 tracks the update's CPU a row 3-4 % less)."""
    m, n, b = mx.shape
    d = n // 3
    for q in range(b):
        i = min(lo + q, len(rows) - 1)
        row = rows[i]
        h[q] = dt[i]
        for j in range(m):
            mu[j, q] = mode_prob[row, j]
            s = n if _accelerating(kinds[j]) else 2 * d
            for a in range(s):
                mx[j, a, q] = mode_x[row, j, a]
                for e in range(a, s):
                    mp[j, a, e, q] = mode_p[row, j, a, e]


@njit(**JIT, inline="always")
def _mixed_predictions(mx, mp, mu, h, tau, dest, kinds, qs, ws, w, c, xp, pp, wk, wv, dv, tv,
                       tc):  # pragma: no cover - compiled
    """The predicted mode probabilities c and each mode's prediction xp, pp over h from
    its mixed initial condition (its first s components: a CV mode's position and
    velocity)."""
    m, n = mx.shape[0], mx.shape[1]
    d = n // 3
    _weights(mu, h, tau, dest, w, c)
    for j in range(m):
        s = n if _accelerating(kinds[j]) else 2 * d  # a CV mode: position and velocity
        _mix(mx, mp, w, dest, kinds, j, s, d, xp[j], pp[j], dv)
        if kinds[j] == 2:  # a coordinated turn at the known rate ws[j]
            _predict_ct(xp[j], pp[j], d, h, ws[j], qs[j], wk[0])
        elif kinds[j] == 3:  # the turn at its state's own rate, at most ws[j]
            _predict_turn(xp[j], pp[j], d, h, ws[j], qs[j], wk[0], tv, tc)
        else:
            _predict(xp[j], pp[j], s, 3 if kinds[j] == 1 else 2, d, h, qs[j],
                     ws[j] if kinds[j] == 0 else 0.0, wk[0], wv)


@njit(**JIT)
def _weights(mu, h, tau, dest, w, c):  # pragma: no cover - compiled
    """Mixing weights w[i, j] = pi_ij mu_i / c_j and the predicted mode probabilities
    c_j = sum_i pi_ij mu_i, pi over each row's |dt| as `IMM.transition`."""
    m, b = mu.shape
    for a in range(m):
        for q in range(b):
            stay = math.exp(-abs(h[q]) / tau[a])
            for e in range(m):
                w[a, e, q] = (stay if a == e else (1.0 - stay) * dest[a, e]) * mu[a, q]
    for e in range(m):
        for q in range(b):
            c[e, q] = 0.0
        for a in range(m):
            for q in range(b):
                c[e, q] += w[a, e, q]
        for a in range(m):
            for q in range(b):
                w[a, e, q] /= max(c[e, q], 1e-300)


@njit(**JIT)
def _mix(mx, mp, w, dest, kinds, j, s, d, x0, p0, dv):  # pragma: no cover - compiled
    """Mode j's mixed initial condition (its first s components) into x0 (n, B) and
    p0 (n, n, B): a CV mode i mixed into a CA mode j takes j's acceleration and its
    covariance block, with no cross terms. A mode j cannot come from is skipped."""
    m, b = mx.shape[0], mx.shape[2]
    x0[:s] = 0.0
    for a in range(s):
        for e in range(a, s):
            p0[a, e] = 0.0
    for pas in range(2):  # the mean, then the spread about it
        for i in range(m):
            if i != j and dest[i, j] == 0.0:
                continue
            # i's own components (a mode without acceleration: j's own acceleration)
            top = 2 * d if _accelerating(kinds[j]) and not _accelerating(kinds[i]) else s
            for a in range(s):
                src = mx[i, a] if a < top else mx[j, a]
                if pas == 0:
                    for q in range(b):
                        x0[a, q] += w[i, j, q] * src[q]
                else:
                    for q in range(b):
                        dv[a, q] = src[q] - x0[a, q]
            if pas == 0:
                continue
            for a in range(s):
                for e in range(a, s):
                    if a < top and e < top:
                        for q in range(b):
                            p0[a, e, q] += w[i, j, q] * (mp[i, a, e, q] + dv[a, q] * dv[e, q])
                    elif a >= top:  # both of j's acceleration
                        for q in range(b):
                            p0[a, e, q] += w[i, j, q] * (mp[j, a, e, q] + dv[a, q] * dv[e, q])
                    else:
                        for q in range(b):
                            p0[a, e, q] += w[i, j, q] * (dv[a, q] * dv[e, q])
    for a in range(s):
        for e in range(a + 1, s):
            p0[e, a] = p0[a, e]


@njit(**JIT)
def _predict(x, p, s, order, d, h, qn, cap, tmp, wv):  # pragma: no cover - compiled
    """x (n, B), P (n, n, B), their first s = order d components, over each row's dt in
    place: F = kron(Phi, I_d), Phi[a, a + k] = dt^k / k!, Q = q^2 kron(C, I_d) with
    C[a, e] = |dt|^(k + 1) / ((o-1-a)! (o-1-e)! k), k = 2 o - 1 - a - e (the continuous
    white noise of density q^2 |dt|, as `models.noise_terms`); q = qn, at most cap / |dt|
    when cap > 0 (`imm.cv_noise`)."""
    b = x.shape[1]
    pw, g, g2 = wv[0], wv[1], wv[2]  # dt^k / k!; |dt|^k for k = 1 .. 3 and 4 .. 6
    q2 = wv[3, 0]  # each row's q^2
    for q in range(b):
        t = h[q]
        pw[0, q], pw[1, q], pw[2, q] = 1.0, t, 0.5 * t * t
        at = abs(t)
        a2 = at * at
        a3 = a2 * at
        g[0, q], g[1, q], g[2, q] = at, a2, a3
        g2[0, q], g2[1, q], g2[2, q] = a3 * at, a3 * a2, a3 * a3
        qe = min(qn, cap / max(at, 1e-300)) if cap > 0.0 else qn
        q2[q] = qe * qe
    for a in range(order):  # x <- F x (block a reads blocks c >= a, not yet changed)
        for k in range(d):
            for c in range(a + 1, order):
                for q in range(b):
                    x[a * d + k, q] += pw[c - a, q] * x[c * d + k, q]
    for a in range(order):  # tmp = F P
        for k in range(d):
            for col in range(s):
                for q in range(b):
                    tmp[a * d + k, col, q] = p[a * d + k, col, q]
                for c in range(a + 1, order):
                    for q in range(b):
                        tmp[a * d + k, col, q] += pw[c - a, q] * p[c * d + k, col, q]
    for r in range(s):  # P = tmp F' + Q, upper triangle, mirrored
        a, k = r // d, r % d
        for col in range(r, s):
            e, el = col // d, col % d
            for q in range(b):
                p[r, col, q] = tmp[r, col, q]
            for f in range(e + 1, order):
                for q in range(b):
                    p[r, col, q] += pw[f - e, q] * tmp[r, f * d + el, q]
            if k == el:
                n1 = 2 * order - 1 - a - e
                den = float(_FACT[order - 1 - a] * _FACT[order - 1 - e] * n1)
                for q in range(b):
                    gk = g[n1, q] if n1 < 3 else g2[n1 - 3, q]  # |dt|^(n1 + 1)
                    p[r, col, q] += q2[q] / den * gk
            for q in range(b):
                p[col, r, q] = p[r, col, q]


@njit(**JIT)
def _predict_ct(x, p, d, h, w, qn, co):  # pragma: no cover - compiled
    """`_predict` of a coordinated turn at the rate w (rad/s, counter-clockwise in x-y) on
    the first 2 d components: the x-y position and velocity turned (Bar-Shalom, Li &
    Kirubarajan 2001, sec. 11.7.1; `models.motion`'s "ct"), the other axes CV, the CV's
    white-noise Q. F = [[I, A], [0, R]] (R the velocity's rotation by w dt in x-y, A its
    integral; identity and dt on the other axes) is applied as row and then column
    operations (F P F' in about a third of a dense product's work)."""
    b, s = x.shape[1], 2 * d
    for q in range(b):  # co: sin/w, (1 - cos)/w, cos, sin; dt, |dt|^2..4
        t = h[q]
        sn, cs, at = math.sin(w * t), math.cos(w * t), abs(t)
        co[0, 0, q], co[0, 1, q], co[0, 2, q], co[0, 3, q] = sn / w, (1.0 - cs) / w, cs, sn
        co[1, 0, q], co[1, 1, q] = t, at * at
        co[1, 2, q], co[1, 3, q] = at * at * at, at * at * at * at
    for q in range(b):  # x <- F x
        v0, v1 = x[d, q], x[d + 1, q]
        x[0, q] += co[0, 0, q] * v0 - co[0, 1, q] * v1
        x[1, q] += co[0, 1, q] * v0 + co[0, 0, q] * v1
        x[d, q] = co[0, 2, q] * v0 - co[0, 3, q] * v1
        x[d + 1, q] = co[0, 3, q] * v0 + co[0, 2, q] * v1
    for k in range(2, d):
        for q in range(b):
            x[k, q] += co[1, 0, q] * x[d + k, q]
    for c in range(s):  # P <- F P, row operations
        for q in range(b):
            v0, v1 = p[d, c, q], p[d + 1, c, q]
            p[0, c, q] += co[0, 0, q] * v0 - co[0, 1, q] * v1
            p[1, c, q] += co[0, 1, q] * v0 + co[0, 0, q] * v1
            p[d, c, q] = co[0, 2, q] * v0 - co[0, 3, q] * v1
            p[d + 1, c, q] = co[0, 3, q] * v0 + co[0, 2, q] * v1
        for k in range(2, d):
            for q in range(b):
                p[k, c, q] += co[1, 0, q] * p[d + k, c, q]
    for r in range(s):  # P <- P F', column operations
        for q in range(b):
            v0, v1 = p[r, d, q], p[r, d + 1, q]
            p[r, 0, q] += co[0, 0, q] * v0 - co[0, 1, q] * v1
            p[r, 1, q] += co[0, 1, q] * v0 + co[0, 0, q] * v1
            p[r, d, q] = co[0, 2, q] * v0 - co[0, 3, q] * v1
            p[r, d + 1, q] = co[0, 3, q] * v0 + co[0, 2, q] * v1
        for k in range(2, d):
            for q in range(b):
                p[r, k, q] += co[1, 0, q] * p[r, d + k, q]
    for r in range(s):  # + Q (upper triangle), mirrored
        a, k = r // d, r % d
        for col in range(r, s):
            e2, el = col // d, col % d
            if k == el:  # the CV's continuous white noise, as `_predict` with order 2
                n1 = 3 - a - e2
                qq = qn * qn / n1
                for q in range(b):
                    p[r, col, q] += qq * co[1, n1, q]  # |dt|^(n1 + 1)
            for q in range(b):
                p[col, r, q] = p[r, col, q]


@njit(**JIT, inline="always")
def _accelerating(kind):  # pragma: no cover - compiled
    """Whether a mode of this kind (0 CV, 1 CA, 2 CT, 3 turn) estimates the acceleration."""
    return kind == 1 or kind == 3


TURN_COEFFS = 20  # per row: Phi (6), dPhi/domega (6), Q (6), omega, and h' P h


@njit(**JIT)
def _predict_turn(x, p, d, h, cap, qn, tmp, tv, co):  # pragma: no cover - compiled
    """`_predict` of the 3-D coordinated turn at each row's own rate omega = |v x a| /
    |v|^2 (at most `cap`) on the whole order-3 state: x <- (Phi x I) x and the EKF's
    P <- J P J' + Q, J = F + g h' with g = (dPhi/domega x I) x and h = domega/dx, as
    J P J' = F P F' + w g' + g w' + (h' P h) g g', w = F P h (`turn.turn_model`, its
    reference; the formulas and their sources there)."""
    b, n = x.shape[1], 3 * d
    hv, g, u, wv = tv[0], tv[1], tv[2], tv[3]
    for q in range(b):  # the rate and its gradient h (zero on the position)
        v0, v1, a0, a1 = x[d, q], x[d + 1, q], x[2 * d, q], x[2 * d + 1, q]
        v2 = x[d + 2, q] if d == 3 else 0.0
        a2 = x[2 * d + 2, q] if d == 3 else 0.0
        c0, c1, c2 = v1 * a2 - v2 * a1, v2 * a0 - v0 * a2, v0 * a1 - v1 * a0
        nn = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        sv = v0 * v0 + v1 * v1 + v2 * v2
        rate = nn / max(sv, 1.0)
        om = min(rate, cap) if sv > 1.0 else 0.0
        for a in range(n):
            hv[a, q] = 0.0
        if sv > 1.0 and nn > 1e-12 * max(sv, 1.0) and rate < cap:
            ns, k2 = nn * sv, 2.0 * nn / (sv * sv)
            dv = ((a1 * c2 - a2 * c1) / ns - k2 * v0, (a2 * c0 - a0 * c2) / ns - k2 * v1,
                  (a0 * c1 - a1 * c0) / ns - k2 * v2)
            da = ((c1 * v2 - c2 * v1) / ns, (c2 * v0 - c0 * v2) / ns, (c0 * v1 - c1 * v0) / ns)
            for k in range(d):
                hv[d + k, q], hv[2 * d + k, q] = dv[k], da[k]
        t = h[q]
        y = om * t
        sn, cs = math.sin(y), math.cos(y)
        if om != 0.0:
            hs = math.sin(0.5 * y)
            co[0, q], co[1, q] = sn / om, 2.0 * hs * hs / (om * om)
        else:
            co[0, q], co[1, q] = t, 0.5 * t * t
        co[2, q], co[3, q], co[4, q], co[5, q] = cs, co[0, q], -om * sn, cs  # f11 f12 f21 f22
        if abs(y) < TURN_SMALL:  # the series of `turn.turn_model`
            t3, o3 = t * t * t, om * om * om
            co[6, q] = -om * t3 / 3.0 + o3 * t3 * t * t / 30.0
            co[7, q] = -om * t3 * t / 12.0 + o3 * t3 * t3 / 180.0
        else:
            co[6, q] = (y * cs - sn) / (om * om)
            co[7, q] = (y * sn - 2.0 * (1.0 - cs)) / (om * om * om)
        co[8, q], co[9, q], co[10, q], co[11, q] = -t * sn, co[6, q], -sn - y * cs, -t * sn
        at = abs(t)
        yq = om * at
        if abs(yq) < TURN_SMALL:  # `turn.turn_noise_series`, density |dt|
            t2, w2 = at * at, om * om
            w4, t4 = w2 * w2, t2 * t2
            co[12, q] = t4 * at * (1 / 20 - w2 * t2 / 168 + w4 * t4 / 2880) * at
            co[13, q] = t4 * (1 / 8 - w2 * t2 / 48 + w4 * t4 / 640) * at
            co[14, q] = t2 * at * (1 / 6 - 7 * w2 * t2 / 120 + 31 * w4 * t4 / 5040) * at
            co[15, q] = t2 * at * (1 / 3 - w2 * t2 / 15 + 2 * w4 * t4 / 315) * at
            co[16, q] = t2 * (1 / 2 - w2 * t2 / 6 + w4 * t4 / 45) * at
            co[17, q] = at * (1 - w2 * t2 / 3 + w4 * t4 / 15) * at
        else:
            s1, s2, w2 = math.sin(yq), math.sin(2.0 * yq), om * om
            hq = math.sin(0.5 * yq)
            co[12, q] = (1.5 * at - 2.0 * s1 / om + s2 / (4.0 * om)) / (w2 * w2) * at
            co[13, q] = (2.0 * hq * hq - 0.5 * s1 * s1) / (w2 * w2) * at
            co[14, q] = (s1 / om - 0.5 * at - s2 / (4.0 * om)) / w2 * at
            co[15, q] = (0.5 * at - s2 / (4.0 * om)) / w2 * at
            co[16, q] = 0.5 * s1 * s1 / w2 * at
            co[17, q] = (0.5 * at + s2 / (4.0 * om)) * at
    for r in range(n):  # u = P h, h' P h
        for q in range(b):
            u[r, q] = 0.0
        for c in range(d, n):
            for q in range(b):
                u[r, q] += p[r, c, q] * hv[c, q]
    for q in range(b):
        co[19, q] = 0.0
    for c in range(d, n):
        for q in range(b):
            co[19, q] += hv[c, q] * u[c, q]
    for k in range(d):  # g = (dPhi x I) x, w = (Phi x I) u, x <- (Phi x I) x
        for q in range(b):
            pk, vk, ak = x[k, q], x[d + k, q], x[2 * d + k, q]
            g[k, q] = co[6, q] * vk + co[7, q] * ak
            g[d + k, q] = co[8, q] * vk + co[9, q] * ak
            g[2 * d + k, q] = co[10, q] * vk + co[11, q] * ak
            x[k, q] = pk + co[0, q] * vk + co[1, q] * ak
            x[d + k, q] = co[2, q] * vk + co[3, q] * ak
            x[2 * d + k, q] = co[4, q] * vk + co[5, q] * ak
            pk, vk, ak = u[k, q], u[d + k, q], u[2 * d + k, q]
            wv[k, q] = pk + co[0, q] * vk + co[1, q] * ak
            wv[d + k, q] = co[2, q] * vk + co[3, q] * ak
            wv[2 * d + k, q] = co[4, q] * vk + co[5, q] * ak
    for k in range(d):  # tmp = (Phi x I) P, row operations
        for col in range(n):
            for q in range(b):
                pk, vk, ak = p[k, col, q], p[d + k, col, q], p[2 * d + k, col, q]
                tmp[k, col, q] = pk + co[0, q] * vk + co[1, q] * ak
                tmp[d + k, col, q] = co[2, q] * vk + co[3, q] * ak
                tmp[2 * d + k, col, q] = co[4, q] * vk + co[5, q] * ak
    for r in range(n):  # P = tmp (Phi x I)' + w g' + g w' + (h'Ph) g g' + Q, mirrored
        a, k = r // d, r % d
        for col in range(r, n):
            e, el = col // d, col % d
            i0, i1 = (0, 1) if e == 0 else ((2, 3) if e == 1 else (4, 5))
            for q in range(b):
                v = co[i0, q] * tmp[r, d + el, q] + co[i1, q] * tmp[r, 2 * d + el, q]
                p[r, col, q] = v + wv[r, q] * g[col, q] + g[r, q] * wv[col, q] \
                    + co[19, q] * g[r, q] * g[col, q]
            if e == 0:
                for q in range(b):
                    p[r, col, q] += tmp[r, el, q]
            if k == el:
                lo, hi = min(a, e), max(a, e)
                idx = 12 + 3 * lo - lo * (lo - 1) // 2 + hi - lo
                for q in range(b):
                    p[r, col, q] += qn * qn * co[idx, q]
            for q in range(b):
                p[col, r, q] = p[r, col, q]



@njit(**JIT)
def _inverse(s0, d, si, det, low, piv):  # pragma: no cover - compiled
    """(S + S_FLOOR I)^-1 of each row's symmetric d x d S into si and its determinant into
    det, through S = L D L' (Golub & Van Loan 2013, alg. 4.1.1; no pivoting: S is a
    covariance); then S^-1 = L^-T D^-1 L^-1. A zero pivot gives NaN."""
    b = s0.shape[2]
    for q in range(b):
        det[q] = 1.0
    for j in range(d):
        for q in range(b):
            v = s0[j, j, q] + S_FLOOR
            for r in range(j):
                v -= low[j, r, q] * low[j, r, q] * piv[r, q]
            piv[j, q] = v
            det[q] *= v
        for i in range(j + 1, d):
            for q in range(b):
                u = s0[i, j, q]
                for r in range(j):
                    u -= low[i, r, q] * low[j, r, q] * piv[r, q]
                low[i, j, q] = u / piv[j, q]
    for j in range(d):  # low <- L^-1 below the diagonal, column by column
        for i in range(j + 1, d):
            for q in range(b):
                v = -low[i, j, q]
                for r in range(j + 1, i):
                    v -= low[i, r, q] * low[r, j, q]
                low[i, j, q] = v
    for i in range(d):
        for j in range(i, d):
            for q in range(b):
                v = (1.0 if j == i else low[j, i, q]) / piv[j, q]
                for r in range(j + 1, d):
                    v += low[r, i, q] * low[r, j, q] / piv[r, q]
                si[i, j, q] = v
                si[j, i, q] = v


@njit(**JIT)
def _time_term(x, p, d, st2, out):  # pragma: no cover - compiled
    """T = sigma_t^2 (v v' + P_vv) (d, d, B) of the prediction x (n, B), P (n, n, B) where
    st2 = sigma_t^2 > 0, zero elsewhere (`timing.time_term`, its reference)."""
    b = out.shape[2]
    for q in range(b):
        s2 = st2[q]
        for a in range(d):
            for c in range(d):
                out[a, c, q] = s2 * (x[d + a, q] * x[d + c, q] + p[d + a, d + c, q]) \
                    if s2 > 0.0 else 0.0


@njit(**JIT)
def _component(r, t, scale, out):  # pragma: no cover - compiled
    """A component's R (d, d, B): r + scale t."""
    d, b = r.shape[0], r.shape[2]
    for a in range(d):
        for c in range(d):
            for q in range(b):
                out[a, c, q] = r[a, c, q] + scale * t[a, c, q]


@njit(**JIT)
def _merge(x, p, lw, fin, xc, pc, lc, fc, st2, n, dv):  # pragma: no cover - compiled
    """The Gaussian (x, P) of log-weight lw and (xc, Pc) of log-weight lc as one, by their
    moments, in place of the first (lw: the sum's log-weight), where st2 > 0
    (`timing.mixture_update`, its reference)."""
    b = x.shape[1]
    for q in range(b):
        if st2[q] > 0.0:
            top = max(lw[q], lc[q])
            ea, ec = math.exp(lw[q] - top), math.exp(lc[q] - top)
            tot = ea + ec
            wa, wc = ea / tot, ec / tot
            lw[q] = top + math.log(tot)
            fin[q] = fin[q] and fc[q] and math.isfinite(lw[q])
            for a in range(n):
                dv[a, q] = x[a, q] - xc[a, q]
                x[a, q] = wa * x[a, q] + wc * xc[a, q]
            for a in range(n):  # the spread of the two about their mean: wa wc d d'
                for e in range(n):
                    p[a, e, q] = wa * p[a, e, q] + wc * pc[a, e, q] \
                        + wa * wc * dv[a, q] * dv[e, q]


@njit(**JIT)
def _update(x, p, s, d, z, r, xo, po, lik, fin, wk, w33, wv):  # pragma: no cover - compiled
    """The CMKF update (H = [I 0]) of x (n, B), P (n, n, B), their first s components,
    into xo, po (the rest zero): K' = S^-1 P[:d], E' = P[:d] - S0 K' with S0 = P[:d, :d]
    + R, P+ = P - [K E][P[:d]; K']; the log-likelihood and whether it is all finite."""
    b = x.shape[1]
    s0, si, low, kt, et = w33[0], w33[1], w33[2], wk[1, :3], wk[2, :3]
    nu, sn, det, piv = wv[0], wv[1], wv[2, 0], wv[3]
    for a in range(d):
        for e in range(d):
            for q in range(b):
                s0[a, e, q] = p[a, e, q] + r[a, e, q]
        for q in range(b):
            nu[a, q] = z[a, q] - x[a, q]
    _inverse(s0, d, si, det, low, piv)
    for a in range(d):
        for col in range(s):
            for q in range(b):
                kt[a, col, q] = 0.0
            for e in range(d):
                for q in range(b):
                    kt[a, col, q] += si[a, e, q] * p[e, col, q]
    for a in range(d):
        for col in range(s):
            for q in range(b):
                et[a, col, q] = p[a, col, q]
            for e in range(d):
                for q in range(b):
                    et[a, col, q] -= s0[e, a, q] * kt[e, col, q]
    for a in range(d):
        for q in range(b):
            sn[a, q] = 0.0
        for e in range(d):
            for q in range(b):
                sn[a, q] += si[a, e, q] * nu[e, q]
    for col in range(s):
        for q in range(b):
            xo[col, q] = x[col, q]
        for a in range(d):
            for q in range(b):
                xo[col, q] += kt[a, col, q] * nu[a, q]
    for i in range(s):
        for j in range(i, s):
            for q in range(b):
                po[i, j, q] = p[i, j, q]
            for a in range(d):
                for q in range(b):
                    po[i, j, q] -= kt[a, i, q] * p[a, j, q] + et[a, i, q] * kt[a, j, q]
            for q in range(b):
                po[j, i, q] = po[i, j, q]
    xo[s:] = 0.0
    po[s:] = 0.0
    po[:s, s:] = 0.0
    for q in range(b):
        nis = 0.0
        for a in range(d):
            nis += nu[a, q] * sn[a, q]
        tot = nis
        for col in range(s):
            tot += xo[col, q]
            for e in range(s):
                tot += po[col, e, q]
        fin[q] = math.isfinite(tot)  # a sum is finite if all its terms are (but overflow)
        dq = det[q]
        lik[q] = -0.5 * (nis + math.log(dq) + d * LOG_2PI) if dq > 0 else -np.inf


@njit(**JIT)
def _probabilities(c, lik, fin, mu, good):  # pragma: no cover - compiled
    """The new mode probabilities mu_j ~ c_j exp(lik_j) (logs, largest first) and
    good[q] = 1.0 where every mode is finite; a non-finite probability weighs 0."""
    m, b = c.shape
    for q in range(b):
        top = -np.inf
        for j in range(m):
            lik[j, q] += math.log(max(c[j, q], 1e-300))
            top = max(top, lik[j, q])
        tot = 0.0
        for j in range(m):
            mu[j, q] = math.exp(lik[j, q] - top)
            tot += mu[j, q]
        good[q] = 1.0
        for j in range(m):
            mu[j, q] /= tot
            if not (fin[j, q] and math.isfinite(mu[j, q])):
                good[q] = 0.0
        for j in range(m):
            if not math.isfinite(mu[j, q]):
                mu[j, q] = 0.0


@njit(**JIT)
def _moments(x, p, w, n, mean, cov, dv):  # pragma: no cover - compiled
    """Mean (n, B) and covariance (n, n, B) of the mixtures of (x_j, P_j) (first n
    components) with weights w (M, B)."""
    m, b = w.shape
    mean[:n] = 0.0
    for j in range(m):
        for a in range(n):
            for q in range(b):
                mean[a, q] += w[j, q] * x[j, a, q]
    for a in range(n):
        for e in range(a, n):
            for q in range(b):
                cov[a, e, q] = 0.0
    for j in range(m):
        for a in range(n):
            for q in range(b):
                dv[a, q] = x[j, a, q] - mean[a, q]
        for a in range(n):
            for e in range(a, n):
                for q in range(b):
                    cov[a, e, q] += w[j, q] * (p[j, a, e, q] + dv[a, q] * dv[e, q])
    for a in range(n):
        for e in range(a + 1, n):
            for q in range(b):
                cov[e, a, q] = cov[a, e, q]


@njit(**JIT)
def _mixture_nis(mean, spread, rr, c, z, d, nis, lo, k, w33, wv):  # pragma: no cover
    """NIS of z against the mixture of the modes' predicted positions (mean, spread;
    weights c), with R averaged the same way: sum_j c_j R_j (as `IMM.update`), into
    nis[lo:lo + B] (the rows below k)."""
    m, b = c.shape
    for j in range(m):
        for a in range(d):
            for e in range(d):
                for q in range(b):
                    spread[a, e, q] += c[j, q] * rr[j, a, e, q]
    si, low, det, piv = w33[0], w33[1], wv[2, 0], wv[3]
    _inverse(spread, d, si, det, low, piv)
    for q in range(min(b, k - lo)):
        v = 0.0
        for a in range(d):
            for e in range(d):
                v += (z[a, q] - mean[a, q]) * si[a, e, q] * (z[e, q] - mean[e, q])
        nis[lo + q] = v


@njit(**JIT)
def point(polar, val, sig, org, d, z, const):  # pragma: no cover - compiled
    """The converted measurements z (d, B): the UCM point (Mo et al. 1998) moved to the
    common frame, or the Cartesian position as given (val, sig (d, B), org (3, B)); and
    the constants of each row's noise, the same for every mode, into const (13, B)."""
    b = z.shape[1]
    for q in range(b):
        if not polar[q]:
            for a in range(d):
                z[a, q] = val[a, q]
            for a in range(CONSTS):  # benign numbers for the polar arithmetic it skips
                const[a, q] = 0.0
            const[CM, q] = const[SAZ2, q] = 1.0
            continue
        saz2 = sig[1, q] * sig[1, q]
        lb = math.exp(-0.5 * saz2)
        sm, cm = math.sin(val[1, q]), math.cos(val[1, q])
        if d == 3:
            sel2 = sig[2, q] * sig[2, q]
            le = math.exp(-0.5 * sel2)
            horiz = val[0, q] * math.cos(val[2, q]) / (lb * le)
            z[2, q] = val[0, q] * math.sin(val[2, q]) / le + org[2, q]
        else:
            sel2 = 0.0
            horiz = val[0, q] / lb
        z[0, q] = horiz * sm + org[0, q]
        z[1, q] = horiz * cm + org[1, q]
        sr2 = sig[0, q] * sig[0, q]
        e_az, e_el = math.exp(-saz2), math.exp(-sel2)
        const[SM, q], const[CM, q], const[SR2, q], const[SAZ2, q] = sm, cm, sr2, saz2
        const[SINH_A, q], const[SINH_E, q] = math.sinh(saz2), math.sinh(sel2)
        const[E_AZ, q], const[E_EL, q] = e_az, e_el
        const[G0, q], const[G1, q] = sr2 * e_el, math.expm1(-sel2)
        const[C0, q], const[C1, q] = e_az * math.sinh(sel2), sr2 * e_az * e_el
        const[C2, q] = math.expm1(-saz2 - sel2)


@njit(**JIT)
def noise(polar, sig, org, const, x, p, d, out, mats, vecs):  # pragma: no cover - compiled
    """R (d, d, B) of each row's converted measurement: the UCM error covariance averaged
    over the prediction N(x[:d], P[:d, :d]) (x (n, B), p (n, n, B)) by the 2d-point
    cubature on the symmetric square root of P[:d, :d], each point's azimuth turned toward
    the measured one (`ucm.ucm_expected_soa`), or diag(sigma^2) for a Cartesian one; NaN
    where P[:d, :d] is not finite. Work arrays mats (3, 3, 3, B), vecs (13, 6, B)."""
    b = out.shape[2]
    k2 = 2 * d
    cov, rot, vec = mats[0], mats[1], mats[2]
    rel, bad, wt = vecs[0, :3], vecs[0, 4], vecs[0, 5]
    sn, cs, cterm = vecs[1], vecs[2], vecs[3]
    pts = vecs[4:7]  # (3, 2d, B): coordinate, point, row
    for q in range(b):
        bad[q] = 0.0
    for a in range(d):
        for e in range(d):
            for q in range(b):
                v = p[a, e, q]
                if not math.isfinite(v):
                    bad[q] = 1.0
                cov[a, e, q] = v
        for q in range(b):
            rel[a, q] = x[a, q] - org[a, q]
    for a in range(d):
        for e in range(d):
            for q in range(b):
                if bad[q] != 0.0:
                    cov[a, e, q] = 0.0
    _eigh(cov, d, rot, vec, vecs[7, :3])
    # the points mean +- (sqrt(d) S)[:, i], S = sum_e sqrt(lambda_e) v_e v_e' (an
    # eigenvalue within rounding of zero, below ROUNDING x the largest, is zero)
    lam = vecs[12, :3]
    for q in range(b):
        top = rot[0, 0, q]
        for e in range(1, d):
            top = max(top, rot[e, e, q])
        for e in range(d):
            v = rot[e, e, q]
            lam[e, q] = math.sqrt(d * v) if v > ROUNDING * top else 0.0
    for col in range(d):
        for a in range(d):
            for q in range(b):
                v = 0.0
                for e in range(d):
                    v += lam[e, q] * vec[col, e, q] * vec[a, e, q]
                pts[a, col, q] = rel[a, q] + v
                pts[a, d + col, q] = rel[a, q] - v
    for q in range(b):  # the weight of the measured azimuth against the predicted one
        r0, r1 = rel[0, q], rel[1, q]
        rho2 = r0 * r0 + r1 * r1
        var_t = r1 * r1 * cov[0, 0, q] - 2.0 * r0 * r1 * cov[0, 1, q] + r0 * r0 * cov[1, 1, q]
        var_t = var_t / rho2 if rho2 > 0 else 0.5 * (cov[0, 0, q] + cov[1, 1, q])
        var_az = var_t / max(rho2, 1e-12)
        wt[q] = var_az / (var_az + const[SAZ2, q])
    # each point's azimuth turned toward the measured one by wt times their wrapped
    # difference: sin and cos of the sum from those of the point (x / rho, y / rho) and
    # of the turn. The difference is atan(u), u = tan of it, and sin and cos of the turn
    # are series where both are small (the usual case: every lane the same operations);
    # the other points are computed again with atan2, sin and cos
    fix = vecs[12]
    for k in range(k2):
        for q in range(b):
            px, py = pts[0, k, q], pts[1, k, q]
            rho = math.sqrt(px * px + py * py)
            inv = 1.0 / rho if rho > 0 else 0.0
            sa, ca = px * inv, py * inv if rho > 0 else 1.0
            sm, cm = const[SM, q], const[CM, q]
            cross, dot = sm * ca - cm * sa, cm * ca + sm * sa
            u = cross / dot if dot > 0 else 0.0
            u2 = u * u  # atan(u) to u^15: the rest below 1e-17 of it for |u| <= 0.1
            th = u * (1.0 - u2 * (1.0 / 3.0 - u2 * (0.2 - u2 * (1.0 / 7.0 - u2 * (
                1.0 / 9.0 - u2 * (1.0 / 11.0 - u2 * (1.0 / 13.0 - u2 / 15.0)))))))
            dl = wt[q] * th  # wt in [0, 1]: |dl| <= |th| < 0.1
            d2 = dl * dl  # sin to dl^13, cos to dl^12: the rest below 1e-24 for |dl| < 0.1
            sd = dl * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0 * (
                1.0 - d2 / 72.0 * (1.0 - d2 / 110.0 * (1.0 - d2 / 156.0))))))
            cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (
                1.0 - d2 / 56.0 * (1.0 - d2 / 90.0 * (1.0 - d2 / 132.0)))))
            sn[k, q], cs[k, q] = sa * cd + ca * sd, ca * cd - sa * sd
            fix[k, q] = 0.0 if dot > 0 and abs(u) <= 0.1 and abs(dl) < 0.1 else 1.0
    for k in range(k2):
        for q in range(b):
            if fix[k, q] == 0.0:
                continue
            px, py = pts[0, k, q], pts[1, k, q]
            rho = math.sqrt(px * px + py * py)
            sa, ca = (px / rho, py / rho) if rho > 0 else (0.0, 1.0)
            sm, cm = const[SM, q], const[CM, q]
            dl = wt[q] * math.atan2(sm * ca - cm * sa, cm * ca + sm * sa)
            if abs(dl) < 1e-3:
                d2 = dl * dl
                sd = dl * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0))
                cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0))
            else:
                sd, cd = math.sin(dl), math.cos(dl)
            sn[k, q], cs[k, q] = sa * cd + ca * sd, ca * cd - sa * sd
    if d == 3:
        _sums_3d(pts, sn, cs, const, out, cterm, vecs[7:12], k2)
    else:
        _sums_2d(pts, sn, cs, const, out, cterm, vecs[7], k2)
    for q in range(b):
        if not polar[q]:
            for a in range(d):
                for e in range(d):
                    out[a, e, q] = sig[a, q] * sig[a, q] if a == e else 0.0
        elif bad[q] != 0.0:
            for a in range(d):
                for e in range(d):
                    out[a, e, q] = np.nan


@njit(**JIT)
def _sums_3d(pts, sn, cs, const, out, cterm, sums, k2):  # pragma: no cover - compiled
    """The sums over the 6 points of `ucm._ucm_sums_3d`, over 6, into out (3, 3, B)."""
    b = sn.shape[1]
    s_ce2, s_rho2, s_z2, s_se2 = sums[0, 0], sums[0, 1], sums[0, 2], sums[0, 3]
    fs0, fs1, fc0, fc1 = sums[1, 0], sums[1, 1], sums[1, 2], sums[1, 3]
    for q in range(b):
        s_ce2[q] = s_rho2[q] = s_z2[q] = s_se2[q] = 0.0
        fs0[q] = fs1[q] = fc0[q] = fc1[q] = 0.0
    for k in range(k2):
        for q in range(b):
            x, y, h = pts[0, k, q], pts[1, k, q], pts[2, k, q]
            rh2, z2 = x * x + y * y, h * h
            r2 = rh2 + z2
            inv_r2 = 1.0 / r2 if r2 > 0 else 1.0
            ce2 = rh2 * inv_r2 if r2 > 0 else 1.0  # el = 0 at the origin, as arctan2
            s_ce2[q] += ce2
            s_rho2[q] += rh2
            s_z2[q] += z2
            s_se2[q] += z2 * inv_r2
            sr2 = const[SR2, q]
            cterm[k, q] = (const[C0, q] * r2 + const[C1, q] * ce2 + const[C2, q] * rh2
                           + const[C0, q] * sr2)
            zr1 = math.sqrt(rh2) * h
            zr0 = zr1 * inv_r2
            fs0[q] += zr0 * sn[k, q]
            fs1[q] += zr1 * sn[k, q]
            fc0[q] += zr0 * cs[k, q]
            fc1[q] += zr1 * cs[k, q]
    for q in range(b):
        sr2, g0, g1 = const[SR2, q], const[G0, q], const[G1, q]
        s_b = s_rho2[q] + s_z2[q] + k2 * sr2
        s_a = const[SINH_A, q] * (const[E_EL, q] * (s_rho2[q] + sr2 * s_ce2[q])
                                  + const[SINH_E, q] * s_b)
        s_c = const[C0, q] * s_b + const[C1, q] * s_ce2[q] + const[C2, q] * s_rho2[q]
        out[2, 2, q] = (const[SINH_E, q] * s_b + g0 * s_se2[q] + g1 * s_z2[q]) / k2
        out[0, 2, q] = out[2, 0, q] = (g0 * fs0[q] + g1 * fs1[q]) / k2
        out[1, 2, q] = out[2, 1, q] = (g0 * fc0[q] + g1 * fc1[q]) / k2
        _horizontal(cterm, sn, cs, s_c, s_a, k2, q, out)


@njit(**JIT)
def _sums_2d(pts, sn, cs, const, out, cterm, s_rho2, k2):  # pragma: no cover - compiled
    """The sums over the 4 points of `ucm._ucm_sums_2d`, over 4, into out (2, 2, B)."""
    b = sn.shape[1]
    for q in range(b):
        s_rho2[0, q] = 0.0
    for k in range(k2):
        for q in range(b):
            rh2 = pts[0, k, q] * pts[0, k, q] + pts[1, k, q] * pts[1, k, q]
            s_rho2[0, q] += rh2
            cterm[k, q] = rh2 * math.expm1(-const[SAZ2, q]) + const[SR2, q] * const[E_AZ, q]
    for q in range(b):
        s_a = const[SINH_A, q] * (s_rho2[0, q] + k2 * const[SR2, q])
        s_c = 0.0
        for k in range(k2):
            s_c += cterm[k, q]
        _horizontal(cterm, sn, cs, s_c, s_a, k2, q, out)


@njit(**JIT, inline="always")
def _horizontal(cterm, sn, cs, s_c, s_a, k2, q, out):  # pragma: no cover - compiled
    """The horizontal block a I + c u u' summed over the points, over their number."""
    o01 = o00 = 0.0
    for k in range(k2):
        o01 += cterm[k, q] * sn[k, q] * cs[k, q]
        o00 += cterm[k, q] * sn[k, q] * sn[k, q]
    out[0, 1, q] = out[1, 0, q] = o01 / k2
    out[1, 1, q] = (s_c - o00 + s_a) / k2
    out[0, 0, q] = (o00 + s_a) / k2


@njit(**JIT)
def _eigh(cov, d, a, v, rot):  # pragma: no cover - compiled
    """Eigen-decomposition of each row's symmetric d x d cov by cyclic Jacobi rotations
    (Golub & Van Loan 2013, alg. 8.5.3) until every row's off-diagonal is below 1e-16 of
    its diagonal: the eigenvalues on the diagonal of a, the eigenvectors the columns of
    v ((d, d, B) each)."""
    b = cov.shape[2]
    for i in range(d):
        for j in range(d):
            for q in range(b):
                a[i, j, q] = cov[i, j, q]
                v[i, j, q] = 1.0 if i == j else 0.0
    live = rot[2]  # 1 while a row's off-diagonal is not yet below rounding
    for q in range(b):
        live[q] = 1.0
    for _ in range(SWEEPS):
        done = True
        for q in range(b):  # a row stops as it would alone: its bits do not depend on
            o = 0.0  # the other rows of its block
            s = 0.0
            for i in range(d):
                s += a[i, i, q] * a[i, i, q]
                for j in range(i + 1, d):
                    o += a[i, j, q] * a[i, j, q]
            if o <= 1e-32 * s:
                live[q] = 0.0
            if live[q] != 0.0:
                done = False
        if done:
            break
        cr, sr = rot[0], rot[1]  # each row's rotation (identity where a_pq = 0)
        for p_ in range(d - 1):
            for r in range(p_ + 1, d):
                for q in range(b):
                    apq = a[p_, r, q]
                    theta = (a[r, r, q] - a[p_, p_, q]) / (2.0 * apq if apq != 0.0 else 1.0)
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    t = 0.0 if apq == 0.0 or live[q] == 0.0 else (t if theta >= 0 else -t)
                    cr[q] = 1.0 / math.sqrt(t * t + 1.0)
                    sr[q] = t * cr[q]
                for k in range(d):  # A <- J' A J, V <- V J
                    for q in range(b):
                        akp, akq = a[k, p_, q], a[k, r, q]
                        a[k, p_, q] = cr[q] * akp - sr[q] * akq
                        a[k, r, q] = sr[q] * akp + cr[q] * akq
                for k in range(d):
                    for q in range(b):
                        apk, aqk = a[p_, k, q], a[r, k, q]
                        a[p_, k, q] = cr[q] * apk - sr[q] * aqk
                        a[r, k, q] = sr[q] * apk + cr[q] * aqk
                for k in range(d):
                    for q in range(b):
                        vkp, vkq = v[k, p_, q], v[k, r, q]
                        v[k, p_, q] = cr[q] * vkp - sr[q] * vkq
                        v[k, r, q] = sr[q] * vkp + cr[q] * vkq
