"""The converted measurements of the CMKF: polar measurements become Cartesian points
by the unbiased conversion (UCM, Mo et al., IEEE TAES 34(3), 1998) with the error
covariance averaged over the predicted position, which keeps the gain uncorrelated with
the measurement error (Bordonaro, Willett & Bar-Shalom, IEEE TAES 50(2), 2014).
`cmkf_soa` converts a `MeasurementBatch` with the batch axis last (see `scratch`); the
other functions are vectorised over a leading batch axis. The plain forms these kernels
are tested against are in `polar` and tests/reference/estimation.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import scratch
from .batch import einsum
from .linalg import cos_sin, eigh
from .measurements import MeasurementBatch
from .polar import ucm_covariance, unbiased
from .timing import time_term, timed

# relative size below which an eigenvalue of a prediction's covariance is rounding (zero)
ROUNDING = 1e-12


@dataclass
class CMKFConversion:
    """The converted measurements of a batch for the filters (`filters.Convert`): called
    with predicted states xp (N, n) and covariances pp (N, n, n) it returns z (N, d) and
    R (N, d, d) (`cmkf_arrays`); `filters.cmkf_step` runs `cmkf_soa` on `batch` instead."""

    batch: MeasurementBatch

    def __call__(self, xp: np.ndarray, pp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z, r, term, _ = self.parts(xp, pp)
        return z, r if term is None else r + term

    def parts(self, xp: np.ndarray, pp: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """z, the position's R, and the time's noise T (`timing.time_term`, along the
        predicted velocity) with the mask of its rows (None, None: no row has any): the
        parts of the time noise's mixture (`timing.mixture_update`)."""
        d, b = self.batch.dim, self.batch
        z, r = cmkf_arrays(b, xp[:, :d], pp[:, :d, :d])
        some = timed(b.sigma_t)
        if some is None:
            return z, r, None, None
        v = slice(d, 2 * d)
        return z, r, time_term(xp[:, v], pp[:, v, v], b.sigma_t), some


def cmkf_arrays(batch: MeasurementBatch, pred: np.ndarray | None,
                pred_cov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Converted measurements z (N, d) and covariances R (N, d, d) in the common frame.
    Polar ones use the UCM, with R averaged over the predicted position N(pred, pred_cov)
    (`cmkf_soa`) when given, else evaluated at the converted point (initiation)."""
    n, d = len(batch), batch.dim
    z, r = np.empty((n, d)), np.empty((n, d, d))
    if pred is not None and pred_cov is not None:
        for lo, hi in scratch.chunks(n):
            k = hi - lo
            zs, rs = scratch.buffer("cmkfa.z", (d,), k), scratch.buffer("cmkfa.r", (d, d), k)
            cmkf_soa(batch.rows(lo, hi), scratch.to_soa(pred[lo:hi], "cmkfa.pos"),
                     scratch.to_soa(pred_cov[lo:hi], "cmkfa.cov"), zs, rs)
            np.copyto(z[lo:hi].T, zs)
            np.copyto(scratch.batch_last(r[lo:hi]), rs)
        return z, r
    polar = batch.polar
    some = polar.any()
    if not (some and polar.all()):
        cart = np.flatnonzero(~polar) if some else slice(None)
        z[cart] = batch.values[cart]
        r[cart] = 0.0
        sig2 = np.square(batch.sigmas[cart])
        for i in range(d):
            r[cart, i, i] = sig2[:, i]
    if some:
        vals, sig = batch.values[polar], batch.sigmas[polar]
        el, sel = (vals[:, 2], sig[:, 2]) if d == 3 else (None, None)
        rel = unbiased(vals[:, 0], vals[:, 1], el, sig[:, 1], sel)
        z[polar] = batch.origin[polar, :d] + rel
        r[polar] = ucm_covariance(rel, sig[:, 0], sig[:, 1], sel)
    return z, r


def at_point(batch: MeasurementBatch) -> tuple[np.ndarray, np.ndarray]:
    """`cmkf_arrays(batch, None)`, the conversion at the measured points (gating,
    initiation), computed once per batch and kept in `batch.point`."""
    if batch.point is None:
        if batch.point_of is not None:  # rows of a batch converted before
            (z, r), rows = batch.point_of
            batch.point = z[rows], r[rows]
        else:
            batch.point = cmkf_arrays(batch, None)
    return batch.point


def cmkf_soa(batch: MeasurementBatch, pos: np.ndarray, cov: np.ndarray, z: np.ndarray,
             r: np.ndarray) -> None:
    """Converted measurements of `batch` for targets predicted at positions pos (d, N)
    with covariance cov (d, d, N) (common frame), batch axis last, into z (d, N) and
    R (d, d, N): polar ones by the UCM with R averaged over the prediction
    (`ucm_expected_soa`), Cartesian ones as given with R = diag(sigma^2)."""
    d, n = pos.shape
    polar = batch.polar
    count = np.count_nonzero(polar)
    if count and count == n:
        _polar_soa(batch, pos, cov, z, r)
        return
    if not count and r.flags.c_contiguous:  # all Cartesian: z, R = diag(sigma^2) whole
        # (the diagonal of R as one strided view)
        np.copyto(z, batch.values.T)
        r.fill(0.0)
        np.square(batch.sigmas.T, out=r.reshape(d * d, n)[::d + 1])
        return
    cart = ~polar
    z[:, cart] = batch.values[cart].T
    r[:, :, cart] = 0.0
    sig = batch.sigmas[cart]
    for i in range(d):
        r[i, i, cart] = sig[:, i] ** 2
    if count:  # the polar ones
        idx = np.flatnonzero(polar)
        zp, rp = np.empty((d, len(idx))), np.empty((d, d, len(idx)))
        sub = MeasurementBatch(batch.t[idx], polar[idx], batch.values[idx],
                               batch.sigmas[idx], batch.origin[idx])
        _polar_soa(sub, pos[:, idx], cov[:, :, idx], zp, rp)
        z[:, idx], r[:, :, idx] = zp, rp


def _polar_soa(batch: MeasurementBatch, pos: np.ndarray, cov: np.ndarray, z: np.ndarray,
               r: np.ndarray) -> None:
    d, n = pos.shape
    vals, sig, origin = batch.values, batch.sigmas, batch.origin[:, :d].T
    el, sel = (vals[:, 2], sig[:, 2]) if d == 3 else (None, None)
    # UCM point (as `unbiased`; cos and sin by _cos_sin), sensor-relative, then moved to
    # the common frame
    lb = np.exp(-0.5 * sig[:, 1] ** 2)
    rng, az = vals[:, 0], vals[:, 1]
    if el is None:
        horiz = rng / lb
    else:
        le = np.exp(-0.5 * sel**2)
        cos_el, sin_el = cos_sin(el)
        horiz = rng * cos_el / (lb * le)
        np.multiply(rng, sin_el, out=z[2])
        z[2] /= le
    cos_az, sin_az = cos_sin(az)
    np.multiply(horiz, sin_az, out=z[0])
    np.multiply(horiz, cos_az, out=z[1])
    z += origin
    rel = np.subtract(pos, origin, out=scratch.buffer("cmkf.rel", (d,), n))
    ucm_expected_soa(rel, cov, sig[:, 0], sig[:, 1], sel, az, r)


def ucm_covariance_expected(mean: np.ndarray, cov: np.ndarray, sr: np.ndarray,
                            saz: np.ndarray, sel: np.ndarray | None,
                            az_meas: np.ndarray) -> np.ndarray:
    """Covariance (N, d, d) of the UCM error for a target predicted at N(mean, cov)
    (sensor-relative; mean (N, d), cov (N, d, d)), given the measured azimuth: see
    `ucm_expected_soa`, which this runs chunk by chunk on batch-last copies."""
    n, d = mean.shape
    out = np.empty((n, d, d))
    for lo, hi in scratch.chunks(n):
        o = scratch.buffer("ucmx.out", (d, d), hi - lo)
        ucm_expected_soa(scratch.to_soa(mean[lo:hi], "ucmx.mean"),
                         scratch.to_soa(cov[lo:hi], "ucmx.cov"), sr[lo:hi], saz[lo:hi],
                         None if sel is None else sel[lo:hi], az_meas[lo:hi], o)
        np.copyto(scratch.batch_last(out[lo:hi]), o)
    return out


def ucm_expected_soa(mean: np.ndarray, cov: np.ndarray, sr: np.ndarray, saz: np.ndarray,
                     sel: np.ndarray | None, az_meas: np.ndarray, out: np.ndarray) -> None:
    """Covariance of the UCM error for targets predicted at N(mean, cov), sensor-relative,
    given the measured azimuth, batch axis last: mean (d, N), cov (d, d, N) -> out (d, d, N).

    R depends on where the target truly is, which only the prediction tells: averaging R(p)
    over the prediction (2d-point spherical cubature, Arasaratnam & Haykin, IEEE TAC 54(6),
    2009, on the symmetric square root of cov, so that R does not depend on the choice of
    eigenvectors where eigenvalues repeat) instead of taking R(mean) keeps the filter
    consistent where R changes fast across the predicted region: near the zenith, the
    overhead pass of scenario B. There the prediction hardly knows the azimuth, which
    orients R, while the measured azimuth knows it well; so each cubature point's azimuth is
    moved toward the measured one by the weight w = var_pred / (var_pred + saz^2) of a
    scalar fusion of the two. Far from the zenith w ~ 0 and R keeps no dependence on the
    measurement error (the decorrelation of Bordonaro, Willett & Bar-Shalom, IEEE TAES
    50(2), 2014).
    A row whose cov has a non-finite entry gets NaN (flagged by the caller's check).
    """
    d, n = mean.shape
    k2 = 2 * d
    bad = ~np.isfinite(cov.sum((0, 1)))  # a non-finite entry (or an overflow)
    if bad.any():
        cov = np.where(bad, 0.0, cov)
    vals, vecs = eigh(cov, d)
    # the 2d points mean +- sqrt(d) s_i, s_i the columns of the symmetric square root
    # S = sum_k sqrt(lambda_k) v_k v_k' (unique where eigenvalues repeat, unlike the
    # eigenvectors): pts[i] (2d, N) is coordinate i
    pts, root = scratch.buffer("ucm.pts", (d, k2), n), scratch.buffer("ucm.root", (d,), n)
    # an eigenvalue within rounding of zero (below ROUNDING x the largest) is zero: its
    # square root would be rounding noise magnified
    floor = ROUNDING * np.maximum(np.maximum(vals[0], vals[1]), vals[-1])
    scale = [np.sqrt(d * np.where(vals[k] > floor, vals[k], 0.0)) for k in range(d)]
    term = scratch.buffer("ucm.term", (d,), n)
    for i in range(d):
        np.multiply(vecs[0], scale[0] * vecs[0][i], out=root)
        for k in range(1, d):
            root += np.multiply(vecs[k], scale[k] * vecs[k][i], out=term)
        np.add(mean, root, out=pts[:, i])
        np.subtract(mean, root, out=pts[:, d + i])
    # predicted variance along the tangent (y, -x) / rho
    tangent = root[:2]
    np.copyto(tangent[0], mean[1])
    np.negative(mean[0], out=tangent[1])
    rho2 = einsum("in,in->n", mean[:2], mean[:2])
    var_t = einsum("in,ijn,jn->n", tangent, cov[:2, :2], tangent)
    if (rho2 > 0).all():
        var_t /= rho2
    else:
        var_t = np.where(rho2 > 0, var_t / np.maximum(rho2, 1e-300),
                         0.5 * (cov[0, 0] + cov[1, 1]))
    var_az = var_t / np.maximum(rho2, 1e-12)  # predicted azimuth variance, rad^2
    w = var_az / (var_az + saz * saz)
    x, y = pts[0], pts[1]
    az, turn, sin, cos = (scratch.buffer(f"ucm.{name}", (k2,), n)
                          for name in ("az", "turn", "sin", "cos"))
    np.arctan2(x, y, out=az)
    np.subtract(az_meas, az, out=turn)
    np.divide(turn, 2 * np.pi, out=sin)
    np.round(sin, out=sin)
    sin *= 2 * np.pi
    turn -= sin  # wrapped to [-pi, pi]
    turn *= w
    az += turn
    # cos and sin of the turned azimuth, as cos_sin
    az *= 0.5
    t = np.tan(az, out=az)
    g = np.multiply(t, t, out=turn)
    g += 1.0
    np.divide(2.0, g, out=g)
    np.subtract(g, 1.0, out=cos)
    np.multiply(g, t, out=sin)
    if d == 3:
        _ucm_sums_3d(pts, sin, cos, sr, saz, sel, out)
    else:
        _ucm_sums_2d(pts, sin, cos, sr, saz, out)
    out *= 1.0 / k2
    for i in range(1, d):
        out[i, :i] = out[:i, i]
    if bad.any():
        out[:, :, bad] = np.nan


def _ucm_sums_2d(pts: np.ndarray, sin: np.ndarray, cos: np.ndarray, sr: np.ndarray,
                 saz: np.ndarray, out: np.ndarray) -> None:
    """Sums over the cubature points pts (2, k, N) of `ucm_covariance_polar` (Mo et al.
    1998) in 2-D, regrouped without its O(r^2) cancellation: with u = (sin az, cos az) the
    unit range vector (of the turned azimuth), B = r^2 + sr^2 and E(s) = exp(-s^2),
    R = a I + c u u', a = B sinh(saz^2), c = sr^2 E(saz) - r^2 (1 - E(saz)). Into
    out (2, 2, N) (upper triangle)."""
    k2, n = sin.shape
    sr2, s2a = sr * sr, saz * saz
    rho2 = einsum("ckn,ckn->kn", pts, pts, out=scratch.buffer("ucm.rho2", (k2,), n))
    sum_rho2 = rho2.sum(0)
    sum_a = np.sinh(s2a) * (sum_rho2 + k2 * sr2)
    c = np.multiply(rho2, np.expm1(-s2a), out=rho2)
    c += sr2 * np.exp(-s2a)
    _horizontal(c, c.sum(0), sum_a, sin, cos, out)


def _ucm_sums_3d(pts: np.ndarray, sin: np.ndarray, cos: np.ndarray, sr: np.ndarray,
                 saz: np.ndarray, sel: np.ndarray, out: np.ndarray) -> None:
    """Sums over the cubature points pts (3, k, N) of `ucm_covariance_polar` (Mo et al.
    1998) in 3-D, regrouped without its O(r^2) cancellation, at points of horizontal
    range^2 rho2, height z and turned azimuth (sin, cos), into out (3, 3, N) (upper
    triangle): with u = (sin az, cos az) the unit horizontal range vector, B = r^2 + sr^2,
    E(s) = exp(-s^2) and ce, se the cos and sin of the elevation, the horizontal block is
    a I + c u u' with a = B sinh(saz^2) (sinh(sel^2) + E(sel) ce^2) and
    c = B E(saz) sinh(sel^2) + ce^2 (sr^2 E(saz) E(sel) - r^2 (1 - E(saz) E(sel))); the
    horizontal-vertical block is f u, f = se ce g, and the vertical B sinh(sel^2) + se^2 g,
    with g = sr^2 E(sel) - r^2 (1 - E(sel)). Every term is a constant of the target times
    a function of the point (B = r^2 + sr^2, B ce^2 = rho2 + sr^2 ce^2, se^2 = z^2 / r^2,
    f = z rho (sr^2 E(sel) / r^2 + expm1(-sel^2))), so the sums run over those."""
    k2, n = sin.shape
    sr2, s2a, s2e = sr * sr, saz * saz, sel * sel
    sinh_a, sinh_e, e_az, e_el = np.sinh(s2a), np.sinh(s2e), np.exp(-s2a), np.exp(-s2e)
    z = pts[2]
    pt = scratch.buffer("ucm.pt", (4, k2), n)  # r^2, ce^2, rho2, z^2 of each point
    r2, ce2, rho2, z2 = pt
    inv_r2 = scratch.buffer("ucm.ir2", (k2,), n)
    einsum("ckn,ckn->kn", pts[:2], pts[:2], out=rho2)
    np.multiply(z, z, out=z2)
    np.add(rho2, z2, out=r2)
    if r2.min() > 0:
        np.divide(1.0, r2, out=inv_r2)
        np.multiply(rho2, inv_r2, out=ce2)
    else:  # el = 0 at the origin, as arctan2
        np.divide(1.0, np.where(r2 > 0, r2, 1.0), out=inv_r2)
        ce2[...] = np.where(r2 > 0, rho2 * inv_r2, 1.0)
    sum_ce2, sum_rho2, sum_z2 = pt[1:].sum(1)
    sum_se2 = einsum("kn,kn->n", z2, inv_r2)  # z^2 / r^2
    sum_b = sum_rho2 + sum_z2 + k2 * sr2
    sum_a = sinh_a * (e_el * (sum_rho2 + sr2 * sum_ce2) + sinh_e * sum_b)
    g0, g1 = sr2 * e_el, np.expm1(-s2e)  # g / r^2 = g0 / r^2 + g1
    out[2, 2] = sinh_e * sum_b + g0 * sum_se2 + g1 * sum_z2
    # c = B E(saz) sinh_e + ce^2 sr^2 E(saz) E(sel) + rho2 expm1(-saz^2 - sel^2)
    coef = scratch.buffer("ucm.coef", (3,), n)
    np.multiply(e_az, sinh_e, out=coef[0])
    np.multiply(sr2, e_az * e_el, out=coef[1])
    np.expm1(-s2a - s2e, out=coef[2])
    sum_c = coef[0] * sum_b + coef[1] * sum_ce2 + coef[2] * sum_rho2
    c = einsum("jn,jkn->kn", coef, pt[:3], out=scratch.buffer("ucm.c", (k2,), n))
    c += coef[0] * sr2
    # f = z rho (g0 / r^2 + g1): sums of z rho / r^2 and z rho times sin and cos
    zr = scratch.buffer("ucm.zr", (2, k2), n)
    np.sqrt(rho2, out=zr[1])
    zr[1] *= z
    np.multiply(zr[1], inv_r2, out=zr[0])
    fs, fc = einsum("jkn,kn->jn", zr, sin), einsum("jkn,kn->jn", zr, cos)
    out[0, 2] = g0 * fs[0] + g1 * fs[1]
    out[1, 2] = g0 * fc[0] + g1 * fc[1]
    _horizontal(c, sum_c, sum_a, sin, cos, out)


def _horizontal(c: np.ndarray, sum_c: np.ndarray, sum_a: np.ndarray, sin: np.ndarray,
                cos: np.ndarray, out: np.ndarray) -> None:
    """Sums of the horizontal block a I + c u u' over the points (k, N)."""
    out[0, 1] = einsum("kn,kn,kn->n", c, sin, cos)
    out[0, 0] = einsum("kn,kn,kn->n", c, sin, sin)
    np.subtract(sum_c, out[0, 0], out=out[1, 1])  # sum of c cos^2
    out[0, 0] += sum_a
    out[1, 1] += sum_a
