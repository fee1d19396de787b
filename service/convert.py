"""Measurement conversion: polar radar measurements to Cartesian points with covariance.

Unbiased converted measurement (UCM, Mo, Song, Zhou, Sun & Bar-Shalom, IEEE TAES
34(3), 1998) with its error covariance evaluated at the predicted position, which keeps
the gain uncorrelated with the measurement error (Bordonaro, Willett & Bar-Shalom,
IEEE TAES 50(2), 2014). Formulas rewritten for the compass azimuth of PROTOCOL.md
(x = r cos el sin az, y = r cos el cos az): the math-convention bearing is pi/2 - az.
The filter core's input is a `MeasurementBatch` (columns, built once per batch from the
validated records); `cmkf_soa` converts it with the batch axis last (see `work`), the
other functions are vectorised over a leading batch axis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import chain
from operator import attrgetter
from typing import TYPE_CHECKING

import numpy as np

from . import work

if TYPE_CHECKING:
    from .validate import Measurement


@dataclass
class MeasurementBatch:
    """N measurements of one dimension d as columns: the filter core's input."""

    t: np.ndarray  # (N,) s
    polar: np.ndarray  # (N,) bool: polar (r, az[, el]) or Cartesian position
    values: np.ndarray  # (N, d): (r, az[, el]) or the position
    sigmas: np.ndarray  # (N, d): (sr, saz[, sel]) or the std of each axis
    origin: np.ndarray  # (N, 3): sensor position

    @classmethod
    def of(cls, meas: Sequence[Measurement], dim: int) -> MeasurementBatch:
        """Columns of validated records (`validate.Measurement`) that all have dimension
        `dim` (values and sigmas of `dim` numbers each)."""
        n = len(meas)
        flat = chain.from_iterable

        def column(name: str, width: int) -> np.ndarray:
            a = np.fromiter(flat(map(attrgetter(name), meas)), float)
            if a.size != n * width:
                raise ValueError(f"measurements of mixed dimensions in one {dim}-D batch")
            return a.reshape(n, width)

        return cls(np.fromiter(map(attrgetter("t"), meas), float, n),
                   np.fromiter(map(attrgetter("polar"), meas), bool, n),
                   column("values", dim), column("sigmas", dim), column("sensor_pos", 3))

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dim(self) -> int:
        return self.values.shape[1]

    def rows(self, lo: int, hi: int) -> MeasurementBatch:
        return MeasurementBatch(self.t[lo:hi], self.polar[lo:hi], self.values[lo:hi],
                                self.sigmas[lo:hi], self.origin[lo:hi])


@dataclass
class CMKFConversion:
    """The converted measurements of a batch for the filters (`filters.Convert`): called
    with predicted states xp (N, n) and covariances pp (N, n, n) it returns z (N, d) and
    R (N, d, d) (`cmkf_arrays`); `filters.cmkf_step` runs `cmkf_soa` on `batch` instead."""

    batch: MeasurementBatch

    def __call__(self, xp: np.ndarray, pp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = self.batch.dim
        return cmkf_arrays(self.batch, xp[:, :d], pp[:, :d, :d])


def cmkf_arrays(batch: MeasurementBatch, pred: np.ndarray | None,
                pred_cov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Converted measurements z (N, d) and covariances R (N, d, d) in the common frame.
    Polar ones use the UCM, with R averaged over the predicted position N(pred, pred_cov)
    (`cmkf_soa`) when given, else evaluated at the converted point (initiation)."""
    n, d = len(batch), batch.dim
    z, r = np.empty((n, d)), np.empty((n, d, d))
    if pred is not None and pred_cov is not None:
        for lo, hi in work.chunks(n):
            zs, rs = work.work("cmkfa.z", (d,), hi - lo), work.work("cmkfa.r", (d, d), hi - lo)
            cmkf_soa(batch.rows(lo, hi), work.to_soa(pred[lo:hi], "cmkfa.pos"),
                     work.to_soa(pred_cov[lo:hi], "cmkfa.cov"), zs, rs)
            np.copyto(z[lo:hi].T, zs)
            np.copyto(np.moveaxis(r[lo:hi], 0, -1), rs)
        return z, r
    polar, cart = batch.polar, ~batch.polar
    if cart.any():
        z[cart] = batch.values[cart]
        sig = batch.sigmas[cart]
        r[cart] = sig[:, :, None] * np.eye(d) * sig[:, None, :]
    if polar.any():
        vals, sig = batch.values[polar], batch.sigmas[polar]
        el, sel = (vals[:, 2], sig[:, 2]) if d == 3 else (None, None)
        rel = unbiased(vals[:, 0], vals[:, 1], el, sig[:, 1], sel)
        z[polar] = batch.origin[polar, :d] + rel
        r[polar] = ucm_covariance(rel, sig[:, 0], sig[:, 1], sel)
    return z, r


def cmkf_soa(batch: MeasurementBatch, pos: np.ndarray, cov: np.ndarray, z: np.ndarray,
             r: np.ndarray) -> None:
    """Converted measurements of `batch` for targets predicted at positions pos (d, N)
    with covariance cov (d, d, N) (common frame), batch axis last, into z (d, N) and
    R (d, d, N): polar ones by the UCM with R averaged over the prediction
    (`ucm_expected_soa`), Cartesian ones as given with R = diag(sigma^2)."""
    d = pos.shape[0]
    polar = batch.polar
    if polar.all():
        _polar_soa(batch, pos, cov, z, r)
        return
    cart = ~polar
    if cart.any():
        z[:, cart] = batch.values[cart].T
        r[:, :, cart] = 0.0
        sig = batch.sigmas[cart]
        for i in range(d):
            r[i, i, cart] = sig[:, i] ** 2
    if polar.any():
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
    # UCM point (as `unbiased`), sensor-relative, then moved to the common frame
    lb = np.exp(-0.5 * sig[:, 1] ** 2)
    rng, az = vals[:, 0], vals[:, 1]
    if el is None:
        horiz = rng / lb
    else:
        le = np.exp(-0.5 * sel**2)
        horiz = rng * np.cos(el) / (lb * le)
        np.multiply(rng, np.sin(el), out=z[2])
        z[2] /= le
    np.multiply(horiz, np.sin(az), out=z[0])
    np.multiply(horiz, np.cos(az), out=z[1])
    z += origin
    rel = np.subtract(pos, origin, out=work.work("cmkf.rel", (d,), n))
    ucm_expected_soa(rel, cov, sig[:, 0], sig[:, 1], sel, az, r)


def polar_to_cartesian(r: np.ndarray, az: np.ndarray, el: np.ndarray | None) -> np.ndarray:
    """Plain (biased) conversion, (N, 2) without elevation, (N, 3) with."""
    if el is None:
        return np.stack([r * np.sin(az), r * np.cos(az)], -1)
    ce = np.cos(el)
    return np.stack([r * ce * np.sin(az), r * ce * np.cos(az), r * np.sin(el)], -1)


def cartesian_to_polar(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Range, compass azimuth and (for 3-D points) elevation of points (N, 2|3)."""
    r = np.linalg.norm(p, axis=-1)
    az = np.arctan2(p[:, 0], p[:, 1])
    if p.shape[1] == 2:
        return r, az, None
    return r, az, np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))


def unbiased(r: np.ndarray, az: np.ndarray, el: np.ndarray | None,
             saz: np.ndarray, sel: np.ndarray | None) -> np.ndarray:
    """UCM point: the plain conversion divided by the angle-noise bias factors."""
    lb = np.exp(-0.5 * saz**2)
    z = polar_to_cartesian(r, az, el)
    if el is None:
        return z / lb[:, None]
    le = np.exp(-0.5 * sel**2)
    z[:, :2] /= (lb * le)[:, None]
    z[:, 2] /= le
    return z


def ucm_covariance(p: np.ndarray, sr: np.ndarray, saz: np.ndarray,
                   sel: np.ndarray | None) -> np.ndarray:
    """Covariance (N, d, d) of the UCM error given the true sensor-relative position p
    (N, d). d = 2 needs sel None."""
    r, az, el = cartesian_to_polar(p)
    return ucm_covariance_polar(r, az, el, sr, saz, sel)


def ucm_covariance_polar(r: np.ndarray, az: np.ndarray, el: np.ndarray | None,
                         sr: np.ndarray, saz: np.ndarray, sel: np.ndarray | None
                         ) -> np.ndarray:
    """`ucm_covariance` given the true position in polar form (keeps the azimuth of a
    point at the zenith, where Cartesian coordinates lose it)."""
    p = polar_to_cartesian(r, az, el)
    lb = np.exp(-0.5 * saz**2)
    lb4 = lb**4
    big_b = r**2 + sr**2
    s2a, c2a = np.sin(2 * az), np.cos(2 * az)
    if el is None:
        k = big_b / (2 * lb**2)
        rxx = k * (1 - lb4 * c2a)
        ryy = k * (1 + lb4 * c2a)
        rxy = k * lb4 * s2a
        out = np.empty(p.shape[:1] + (2, 2))
        out[:, 0, 0], out[:, 1, 1], out[:, 0, 1] = rxx, ryy, rxy
        out[:, 1, 0] = rxy
        return out - p[:, :, None] * p[:, None, :]
    le = np.exp(-0.5 * sel**2)
    le4 = le**4
    c2e, s2e = np.cos(2 * el), np.sin(2 * el)
    k = big_b * (1 + le4 * c2e) / (4 * lb**2 * le**2)
    h = big_b / (2 * le**2)
    out = np.empty(p.shape[:1] + (3, 3))
    out[:, 0, 0] = k * (1 - lb4 * c2a)
    out[:, 1, 1] = k * (1 + lb4 * c2a)
    out[:, 0, 1] = out[:, 1, 0] = k * lb4 * s2a
    out[:, 2, 2] = h * (1 - le4 * c2e)
    out[:, 0, 2] = out[:, 2, 0] = h * le4 * s2e * np.sin(az)
    out[:, 1, 2] = out[:, 2, 1] = h * le4 * s2e * np.cos(az)
    return out - p[:, :, None] * p[:, None, :]


def _eigh(a: dict, d: int, n: int) -> tuple[list, list]:
    """Eigenvalues (d arrays of N) and unit eigenvectors (d vectors of d arrays of N) of
    symmetric PSD matrices given by their entries a[i, j] (N,), those of `np.linalg.eigh`
    up to order and signs (and the choice of basis of a repeated eigenvalue), in closed
    form for d <= 3.

    A Jacobi rotation by 0.5 atan2(2 a01, a00 - a11) diagonalises a 2 x 2 block (Golub &
    Van Loan 2013, sec. 8.5.2). For d = 3, the eigenvalue farthest from the other two
    (trigonometric solution of the characteristic cubic: Smith, CACM 4(4), 1961) has its
    eigenvector v along the largest cross product of two rows of cov - lambda I, and a
    Jacobi rotation in the plane orthogonal to v (basis of Duff et al., JCGT 6(1), 2017)
    gives the other two, accurately even when their eigenvalues are close. Per-entry
    arithmetic on (N,) arrays."""
    if d > 3:
        cov = np.array([[a[i, j] for j in range(d)] for i in range(d)]).transpose(2, 0, 1)
        vals, vecs = np.linalg.eigh(cov)
        return list(vals.T), [list(vecs[:, :, k].T) for k in range(d)]

    def times(v: list) -> list:  # cov @ v
        return [sum(a[i, j] * v[j] for j in range(d)) for i in range(d)]

    def dot(u: list, v: list) -> np.ndarray:
        return sum(ui * vi for ui, vi in zip(u, v, strict=True))

    def rotate(u: list, w: list) -> tuple[list, list]:  # eigenpairs of cov in span(u, w)
        cu, cw = times(u), times(w)
        uu, uw, ww = dot(u, cu), dot(u, cw), dot(w, cw)
        c, s = _cos_sin(0.5 * np.arctan2(2 * uw, uu - ww))
        first = c * c * uu + 2 * c * s * uw + s * s * ww  # Rayleigh quotient
        return ([first, uu + ww - first],
                [[c * ui + s * wi for ui, wi in zip(u, w, strict=True)],
                 [c * wi - s * ui for ui, wi in zip(u, w, strict=True)]])

    def shifted(lam: np.ndarray) -> list:  # rows of cov - lam I
        return [[a[i, j] - lam if i == j else a[i, j] for j in range(3)] for i in range(3)]

    one, zero = np.ones(n), np.zeros(n)
    if d == 1:
        return [a[0, 0]], [[one]]
    if d == 2:
        return rotate([one, zero], [zero, one])
    q = (a[0, 0] + a[1, 1] + a[2, 2]) / 3
    b = shifted(q)
    p = np.sqrt((b[0][0] ** 2 + b[1][1] ** 2 + b[2][2] ** 2
                 + 2 * (a[0, 1] ** 2 + a[0, 2] ** 2 + a[1, 2] ** 2)) / 6)
    half = np.divide(dot(b[0], _cross(b[1], b[2])), 2 * p**3, out=zero.copy(),
                     where=p > 0)  # det(cov - q I) / (2 p^3)
    cos_phi, sin_phi = _cos_sin(np.arccos(np.clip(half, -1.0, 1.0)) / 3)
    hi = q + 2 * p * cos_phi
    lo = q - p * (cos_phi + np.sqrt(3) * sin_phi)  # q + 2 p cos(phi + 2 pi / 3)
    iso = np.where(hi + lo > 2 * q, hi, lo)  # hi - mid > mid - lo, as mid = 3q - hi - lo
    rows = shifted(iso)
    v, best = _cross(rows[0], rows[1]), None
    for c in (_cross(rows[0], rows[2]), _cross(rows[1], rows[2])):
        best = dot(v, v) if best is None else best
        c2 = dot(c, c)
        v = [np.where(c2 > best, ci, vi) for ci, vi in zip(c, v, strict=True)]
        best = np.maximum(best, c2)
    scale = np.divide(1.0, np.sqrt(best), out=zero.copy(), where=best > 0)
    v = [v[0] * scale, v[1] * scale, np.where(best > 0, v[2] * scale, 1.0)]  # else any
    sign = np.copysign(1.0, v[2])  # u, w complete v to an orthonormal basis (Duff et al.)
    k = -1 / (sign + v[2])
    e = v[0] * v[1] * k
    pair_vals, pair_vecs = rotate([1 + sign * v[0] ** 2 * k, sign * e, -sign * v[0]],
                                  [e, sign + v[1] ** 2 * k, -v[1]])
    return [iso, *pair_vals], [v, *pair_vecs]


def _cross(u: list, v: list) -> list:
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def _cos_sin(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin from the half-angle tangent t: (1 - t^2) / (1 + t^2), 2t / (1 + t^2)
    (np.tan is much faster than np.sin and np.cos)."""
    t = np.tan(0.5 * angle)
    t2 = t * t
    return (1 - t2) / (1 + t2), 2 * t / (1 + t2)


def ucm_covariance_expected(mean: np.ndarray, cov: np.ndarray, sr: np.ndarray,
                            saz: np.ndarray, sel: np.ndarray | None,
                            az_meas: np.ndarray) -> np.ndarray:
    """Covariance (N, d, d) of the UCM error for a target predicted at N(mean, cov)
    (sensor-relative; mean (N, d), cov (N, d, d)), given the measured azimuth: see
    `ucm_expected_soa`, which this runs chunk by chunk on batch-last copies."""
    n, d = mean.shape
    out = np.empty((n, d, d))
    for lo, hi in work.chunks(n):
        o = work.work("ucmx.out", (d, d), hi - lo)
        ucm_expected_soa(work.to_soa(mean[lo:hi], "ucmx.mean"), work.to_soa(cov[lo:hi], "ucmx.cov"),
                         sr[lo:hi], saz[lo:hi], None if sel is None else sel[lo:hi],
                         az_meas[lo:hi], o)
        np.copyto(np.moveaxis(out[lo:hi], 0, -1), o)
    return out


def ucm_expected_soa(mean: np.ndarray, cov: np.ndarray, sr: np.ndarray, saz: np.ndarray,
                     sel: np.ndarray | None, az_meas: np.ndarray, out: np.ndarray) -> None:
    """Covariance of the UCM error for targets predicted at N(mean, cov), sensor-relative,
    given the measured azimuth, batch axis last: mean (d, N), cov (d, d, N) -> out (d, d, N).

    R depends on where the target truly is, which only the prediction tells: averaging
    R(p) over the prediction (2d-point spherical cubature, Arasaratnam & Haykin, IEEE TAC
    54(6), 2009) instead of taking R(mean) keeps the filter consistent where R changes
    fast across the predicted region: near the zenith, the overhead pass of scenario B.
    There the prediction hardly knows the azimuth, which orients R, while the measured
    azimuth knows it well; so each cubature point's azimuth is moved toward the measured
    one by the weight w = var_pred / (var_pred + saz^2) of a scalar fusion of the two.
    Far from the zenith w ~ 0 and R keeps no dependence on the measurement error (the
    decorrelation of Bordonaro, Willett & Bar-Shalom, IEEE TAES 50(2), 2014).
    A row whose cov has a non-finite entry gets NaN (flagged by the caller's check).
    """
    d, n = mean.shape
    k2 = 2 * d
    bad = ~np.isfinite(cov.sum((0, 1)))  # a non-finite entry (or an overflow)
    if bad.any():
        cov = np.where(bad, 0.0, cov)
    vals, vecs = _eigh({(i, j): cov[min(i, j), max(i, j)] for i in range(d) for j in range(d)},
                       d, n)
    # the 2d points mean +- sqrt(d lambda_k) v_k: pts[i] (2d, N) is coordinate i
    pts = work.work("ucm.pts", (d, k2), n)
    for k in range(d):
        scale = np.sqrt(d * np.maximum(vals[k], 0.0))
        for i in range(d):
            np.multiply(vecs[k][i], scale, out=pts[i, k])
    np.negative(pts[:, :d], out=pts[:, d:])
    pts += mean[:, None]
    x, y = mean[0], mean[1]
    rho2 = x**2 + y**2
    cxx, cxy, cyy = cov[0, 0], cov[0, 1] + cov[1, 0], cov[1, 1]
    var_t = np.where(rho2 > 0, (y**2 * cxx - x * y * cxy + x**2 * cyy) / np.maximum(rho2, 1e-300),
                     0.5 * (cxx + cyy))  # along the tangent (y, -x) / rho
    var_az = var_t / np.maximum(rho2, 1e-12)  # predicted azimuth variance, rad^2
    w = var_az / (var_az + saz**2)
    x, y = pts[0], pts[1]
    az, tmp, tan, sin, cos = (work.work(f"ucm.{name}", (k2,), n)
                              for name in ("az", "tmp", "tan", "sin", "cos"))
    np.arctan2(x, y, out=az)
    turn = np.subtract(az_meas, az, out=tmp)
    turn -= np.multiply(np.round(np.divide(turn, 2 * np.pi, out=sin), out=sin), 2 * np.pi,
                        out=sin)  # wrapped to [-pi, pi]
    turn *= w
    az += turn
    # cos and sin of the turned azimuth from its half-angle tangent, as _cos_sin
    t = np.tan(np.multiply(az, 0.5, out=tan), out=tan)
    t2 = np.multiply(t, t, out=az)
    den = np.add(t2, 1.0, out=tmp)
    np.divide(1.0, den, out=den)
    np.subtract(1.0, t2, out=cos)
    cos *= den
    np.multiply(t, 2.0, out=sin)
    sin *= den
    rho2 = np.multiply(x, x, out=az)
    rho2 += np.multiply(y, y, out=tmp)
    _ucm_sums(rho2, pts[2] if d == 3 else None, sin, cos, sr, saz, sel, out)
    if bad.any():
        out[:, :, bad] = np.nan


def _ucm_sums(rho2: np.ndarray, z: np.ndarray | None, sin: np.ndarray, cos: np.ndarray,
              sr: np.ndarray, saz: np.ndarray, sel: np.ndarray | None, out: np.ndarray
              ) -> None:
    """The mean over the cubature points (2d, N) of `ucm_covariance_polar` (Mo et al. 1998)
    regrouped without its O(r^2) cancellation, at points of horizontal range^2 rho2,
    height z and turned azimuth (sin, cos) into out (d, d, N): with u = (sin az, cos az)
    the unit horizontal range vector, B = r^2 + sr^2 and E(s) = exp(-s^2), in 2-D
    R = a I + c u u', a = B sinh(saz^2), c = sr^2 E(saz) - r^2 (1 - E(saz)).
    In 3-D, with ce, se the cos and sin of the elevation, the horizontal block is a I + c u u'
    with a = B sinh(saz^2) (sinh(sel^2) + E(sel) ce^2) and
    c = B E(saz) sinh(sel^2) + ce^2 (sr^2 E(saz) E(sel) - r^2 (1 - E(saz) E(sel))); the
    horizontal-vertical block is f u, f = se ce g, and the vertical B sinh(sel^2) + se^2 g,
    with g = sr^2 E(sel) - r^2 (1 - E(sel))."""
    k2, n = rho2.shape
    sr2, s2a = sr**2, saz**2
    sinh_a, e_az = np.sinh(s2a), np.exp(-s2a)
    a, c, tmp = (work.work(f"ucm.{name}", (k2,), n) for name in ("a", "c", "t2"))
    if z is None:
        np.add(rho2, sr2, out=a)
        a *= sinh_a
        np.multiply(rho2, np.expm1(-s2a), out=c)
        c += sr2 * e_az
    else:
        s2e = sel**2
        sinh_e, e_el = np.sinh(s2e), np.exp(-s2e)
        z2 = np.multiply(z, z, out=work.work("ucm.z2", (k2,), n))
        big_b = np.add(rho2, z2, out=work.work("ucm.b", (k2,), n))  # r^2 for now
        inv_r2 = work.work("ucm.ir2", (k2,), n)
        if (big_b > 0).all():
            np.divide(1.0, big_b, out=inv_r2)
            ce2 = np.multiply(rho2, inv_r2, out=tmp)
        else:  # el = 0 at the origin, as arctan2
            np.divide(1.0, np.where(big_b > 0, big_b, 1.0), out=inv_r2)
            tmp[...] = np.where(big_b > 0, rho2 * inv_r2, 1.0)
            ce2 = tmp
        big_b += sr2
        # a = B sinh_a (E(sel) ce2 + sinh_e)
        np.multiply(ce2, sinh_a * e_el, out=a)
        a += sinh_a * sinh_e
        a *= big_b
        # c = B E(saz) sinh_e + ce2 sr^2 E(saz) E(sel) + rho2 expm1(-saz^2 - sel^2)
        np.multiply(big_b, e_az * sinh_e, out=c)
        c += np.multiply(ce2, sr2 * e_az * e_el, out=ce2)
        c += np.multiply(rho2, np.expm1(-s2a - s2e), out=tmp)
        # g / r^2 = sr^2 E(sel) / r^2 + expm1(-sel^2); vertical B sinh_e + z^2 g / r^2
        g = np.multiply(inv_r2, sr2 * e_el, out=inv_r2)
        g += np.expm1(-s2e)
        vert = np.multiply(big_b, sinh_e, out=big_b)
        vert += np.multiply(z2, g, out=z2)
        out[2, 2] = vert.sum(0)
        g *= z
        g *= np.sqrt(rho2, out=tmp)  # f = se ce g = z rho g / r^2
        out[0, 2] = np.multiply(g, sin, out=tmp).sum(0)
        out[1, 2] = np.multiply(g, cos, out=tmp).sum(0)
    sum_a, sum_c = a.sum(0), c.sum(0)
    c *= sin
    out[0, 1] = np.multiply(c, cos, out=tmp).sum(0)
    c *= sin
    out[0, 0] = c.sum(0)
    out[1, 1] = sum_c
    out[1, 1] -= out[0, 0]  # sum of c cos^2
    out[0, 0] += sum_a
    out[1, 1] += sum_a
    out *= 1.0 / k2
    if z is not None:
        out[2, 0], out[2, 1] = out[0, 2], out[1, 2]
    out[1, 0] = out[0, 1]


def polar_linearised(rel: np.ndarray, meas: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EKF terms of a polar measurement at predicted sensor-relative positions rel (N, d):
    predicted measurement h(rel) = (r, az[, el]), its Jacobian (N, d, d) with respect to
    the position, and the measurement with its azimuth unwrapped to lie within pi of the
    prediction. Near the zenith the 1/rho^2 azimuth terms blow up: that is the EKF's
    weakness this baseline exists to show (SCENARIOS.md, B)."""
    r, az, el = cartesian_to_polar(rel)
    x, y = rel[:, 0], rel[:, 1]
    rho2 = x**2 + y**2
    d = rel.shape[1]
    jac = np.zeros((len(rel), d, d))
    jac[:, 0] = rel / r[:, None]
    jac[:, 1, 0], jac[:, 1, 1] = y / rho2, -x / rho2
    hx = np.stack([r, az] if el is None else [r, az, el], 1)
    if el is not None:
        rho = np.sqrt(rho2)
        jac[:, 2, 0] = -x * rel[:, 2] / (r**2 * rho)
        jac[:, 2, 1] = -y * rel[:, 2] / (r**2 * rho)
        jac[:, 2, 2] = rho / r**2
    z = meas.copy()
    z[:, 1] = az + np.angle(np.exp(1j * (meas[:, 1] - az)))
    return hx, jac, z
