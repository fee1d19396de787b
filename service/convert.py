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
    """N measurements of one dimension d as columns: the filter core's input (the
    (N, d) arrays are column-major: the kernels read them a column at a time)."""

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
            return np.asfortranarray(a.reshape(n, width))  # each of its columns contiguous

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
    # UCM point (as `unbiased`; cos and sin by _cos_sin), sensor-relative, then moved to
    # the common frame
    lb = np.exp(-0.5 * sig[:, 1] ** 2)
    rng, az = vals[:, 0], vals[:, 1]
    if el is None:
        horiz = rng / lb
    else:
        le = np.exp(-0.5 * sel**2)
        cos_el, sin_el = _cos_sin(el)
        horiz = rng * cos_el / (lb * le)
        np.multiply(rng, sin_el, out=z[2])
        z[2] /= le
    cos_az, sin_az = _cos_sin(az)
    np.multiply(horiz, sin_az, out=z[0])
    np.multiply(horiz, cos_az, out=z[1])
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


def _eigh(cov: np.ndarray, d: int) -> tuple[list, list]:
    """Eigenvalues (d arrays of N) and unit eigenvectors (d arrays (d, N)) of
    symmetric PSD matrices cov (d, d, N) (batch axis last; the upper triangle is read),
    those of `np.linalg.eigh` up to order and signs (and the choice of basis of a repeated
    eigenvalue), in closed form for d <= 3.

    A Jacobi rotation by 0.5 atan2(2 a01, a00 - a11) diagonalises a 2 x 2 block (Golub &
    Van Loan 2013, sec. 8.5.2). For d = 3, the eigenvalue farthest from the other two
    (trigonometric solution of the characteristic cubic: Smith, CACM 4(4), 1961) has its
    eigenvector v along the largest cross product of two rows of cov - lambda I (the
    columns of its adjugate), and a Jacobi rotation in the plane orthogonal to v (basis of
    Duff et al., JCGT 6(1), 2017) gives the other two, accurately even when their
    eigenvalues are close. Per-entry arithmetic on (N,) arrays; for d = 3 some of the
    returned arrays are work arrays of this thread (valid until the next call)."""
    n = cov.shape[-1]
    if d > 3:
        vals, vecs = np.linalg.eigh(np.moveaxis(cov, -1, 0))
        return list(vals.T), [vecs[:, :, k].T for k in range(d)]
    a = {(i, j): cov[min(i, j), max(i, j)] for i in range(d) for j in range(d)}
    if d == 1:
        return [a[0, 0]], [np.ones((1, n))]
    if d == 2:
        uw = np.zeros((2, 2, n))
        uw[0, 0] = uw[1, 1] = 1.0
        return _rotate(cov, uw)
    return _eigh3(cov, a, n)


def _eigh3(cov: np.ndarray, a: dict, n: int) -> tuple[list, list]:
    """`_eigh` for d = 3 on reused work arrays (the same arithmetic, written with out=)."""
    a00, a01, a02, a11, a12, a22 = a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2]
    e = work.work("eig", (34,), n)
    q, b00, b11, b22, t, p, t2, det = e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7]
    np.add(a00, a11, out=q)
    q += a22
    q /= 3
    np.subtract(a00, q, out=b00)
    np.subtract(a11, q, out=b11)
    np.subtract(a22, q, out=b22)
    # p = sqrt((b00^2 + b11^2 + b22^2 + 2 (a01^2 + a02^2 + a12^2)) / 6)
    bq, aq = e[1:4], cov[0, 1:]  # (b00, b11, b22) and (a01, a02)
    np.einsum("kn,kn->n", bq, bq, out=p)
    np.einsum("kn,kn->n", aq, aq, out=t2)
    t2 += np.multiply(a12, a12, out=t)
    t2 *= 2
    p += t2
    p /= 6
    np.sqrt(p, out=p)
    # det(cov - q I) along its first row
    np.multiply(b11, b22, out=det)
    det -= np.multiply(a12, a12, out=t)
    det *= b00
    np.multiply(a12, a02, out=t2)
    t2 -= np.multiply(a01, b22, out=t)
    t2 *= a01
    det += t2
    np.multiply(a01, a12, out=t2)
    t2 -= np.multiply(b11, a02, out=t)
    t2 *= a02
    det += t2
    half = e[8]
    np.multiply(p, p, out=t)
    t *= p
    t *= 2
    _divide(det, t, half, 0.0)  # det / (2 p^3), 0 where p = 0
    np.clip(half, -1.0, 1.0, out=half)
    np.arccos(half, out=half)
    half /= 3
    cos_phi, sin_phi = _cos_sin_into(half, e[9], e[10])
    hi, lo, iso = e[11], e[12], e[13]
    np.multiply(p, 2, out=hi)
    hi *= cos_phi
    hi += q
    np.multiply(sin_phi, np.sqrt(3), out=lo)  # q + 2 p cos(phi + 2 pi / 3)
    lo += cos_phi
    lo *= p
    np.subtract(q, lo, out=lo)
    np.add(hi, lo, out=t)
    q *= 2
    np.copyto(iso, lo)
    np.copyto(iso, hi, where=t > q)  # hi - mid > mid - lo, as mid = 3q - hi - lo
    r00, r11, r22 = b00, b11, b22  # rows of cov - iso I
    np.subtract(a00, iso, out=r00)
    np.subtract(a11, iso, out=r11)
    np.subtract(a22, iso, out=r22)
    # adjugate of cov - iso I: rows 0 x 1 = (u0, u1, d2), 0 x 2 = -(u2, d1, u1),
    # 1 x 2 = (d0, u2, u0)
    d0, d1, d2, u0, u1, u2 = e[14], e[15], e[16], e[17], e[18], e[19]
    for out, (w, x), (y, z) in ((d0, (r11, r22), (a12, a12)), (d1, (r00, r22), (a02, a02)),
                                (d2, (r00, r11), (a01, a01)), (u0, (a01, a12), (a02, r11)),
                                (u1, (a01, a02), (r00, a12)), (u2, (a02, a12), (a01, r22))):
        np.multiply(w, x, out=out)
        out -= np.multiply(y, z, out=t)
    su0, su1, su2, best, c2 = e[20], e[21], e[22], e[23], e[24]
    np.multiply(u0, u0, out=su0)
    np.multiply(u1, u1, out=su1)
    np.multiply(u2, u2, out=su2)
    np.add(su0, su1, out=best)
    best += np.multiply(d2, d2, out=t)
    vec = e[25:28]
    v = list(vec)
    for vi, ci in zip(v, (u0, u1, d2), strict=True):
        np.copyto(vi, ci)
    for cand, (s1, x, s2) in (((u2, d1, u1), (su2, d1, su1)), ((d0, u2, u0), (None, d0, su2))):
        if s1 is None:  # d0^2 + u2^2 + u0^2
            np.multiply(x, x, out=c2)
            c2 += s2
            c2 += su0
        else:  # u2^2 + d1^2 + u1^2
            np.add(s1, np.multiply(x, x, out=t), out=c2)
            c2 += s2
        more = c2 > best
        for vi, ci in zip(v, cand, strict=True):
            np.copyto(vi, ci, where=more)
        np.maximum(best, c2, out=best)
    scale = e[28]
    np.sqrt(best, out=t)
    _divide(1.0, t, scale, 0.0)
    v[0] *= scale
    v[1] *= scale
    v[2] *= scale
    if not best.all():
        np.copyto(v[2], 1.0, where=best == 0)  # any unit vector
    # u, w complete v to an orthonormal basis (Duff et al.)
    sign, k, f = e[29], e[30], e[31]
    np.copysign(1.0, v[2], out=sign)
    np.add(sign, v[2], out=k)
    np.divide(-1.0, k, out=k)
    np.multiply(v[0], v[1], out=f)
    f *= k
    uw = work.work("eig.uw", (2, 3), n)
    u, w = uw
    np.multiply(v[0], v[0], out=u[0])
    u[0] *= k
    u[0] *= sign
    u[0] += 1.0
    np.multiply(sign, f, out=u[1])
    np.multiply(sign, v[0], out=u[2])
    np.negative(u[2], out=u[2])
    np.copyto(w[0], f)
    np.multiply(v[1], v[1], out=w[1])
    w[1] *= k
    w[1] += sign
    np.negative(v[1], out=w[2])
    pair_vals, pair_vecs = _rotate(cov, uw)
    return [iso, *pair_vals], [vec, *pair_vecs]


def _divide(num: np.ndarray | float, den: np.ndarray, out: np.ndarray, fill: float
            ) -> np.ndarray:
    """num / den into out, `fill` where den is 0 (a masked divide only when one is)."""
    if den.all():
        return np.divide(num, den, out=out)
    out.fill(fill)
    return np.divide(num, den, out=out, where=den != 0)


def _cos_sin_into(angle: np.ndarray, cos: np.ndarray, sin: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """`_cos_sin` into given arrays (angle is overwritten)."""
    t = np.multiply(angle, 0.5, out=angle)
    np.tan(t, out=t)
    np.multiply(t, t, out=cos)
    cos += 1.0
    np.divide(2.0, cos, out=cos)
    np.multiply(cos, t, out=sin)
    cos -= 1.0
    return cos, sin


def _rotate(cov: np.ndarray, uw: np.ndarray) -> tuple[list, list]:
    """Eigenpairs of symmetric matrices cov (d, d, N) in the planes of the orthonormal
    vectors uw[0] = u, uw[1] = w (2, d, N): a Jacobi rotation of the 2 x 2 projection.
    The results are work arrays of this thread."""
    d, n = uw.shape[1:]
    e = work.work("rot", (7,), n)
    t, first, cs = e[0], e[1], e[2:4]
    # the projection [[uu, uw], [uw, ww]] = [u w]' (cov [u w])
    cuw = np.einsum("ijn,ajn->ain", cov, uw, out=work.work("rot.c", (2, d), n))
    proj = np.einsum("ain,bin->abn", uw, cuw, out=work.work("rot.p", (2, 2), n))
    uu, uv, ww = proj[0, 0], proj[0, 1], proj[1, 1]
    # 0.5 atan2(2 uw, uu - ww), cos and sin as _cos_sin
    np.subtract(uu, ww, out=t)
    np.multiply(uv, 2, out=first)
    np.arctan2(first, t, out=t)
    t *= 0.5
    c, s = _cos_sin_into(t, cs[0], cs[1])
    # Rayleigh quotient c^2 uu + 2 c s uw + s^2 ww
    np.multiply(c, c, out=first)
    first *= uu
    np.multiply(c, 2, out=t)
    t *= s
    t *= uv
    first += t
    np.multiply(s, s, out=t)
    t *= ww
    first += t
    vecs = work.work("rot.v", (2, d), n)
    np.einsum("jn,jin->in", cs, uw, out=vecs[0])  # c u + s w
    np.negative(s, out=e[4])
    np.copyto(e[5], c)
    np.einsum("jn,jin->in", e[4:6], uw, out=vecs[1])  # c w - s u
    uu += ww
    uu -= first
    return [first, uu], [vecs[0], vecs[1]]


def _cos_sin(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin from the half-angle tangent t: with g = 2 / (1 + t^2), cos = g - 1 and
    sin = g t (np.tan is much faster than np.sin and np.cos)."""
    t = np.tan(0.5 * angle)
    g = t * t
    g += 1.0
    np.divide(2.0, g, out=g)
    return g - 1.0, np.multiply(g, t, out=t)


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
        ucm_expected_soa(work.to_soa(mean[lo:hi], "ucmx.mean"),
                         work.to_soa(cov[lo:hi], "ucmx.cov"), sr[lo:hi], saz[lo:hi],
                         None if sel is None else sel[lo:hi], az_meas[lo:hi], o)
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
    vals, vecs = _eigh(cov, d)
    # the 2d points mean +- sqrt(d lambda_k) v_k: pts[i] (2d, N) is coordinate i
    pts, root = work.work("ucm.pts", (d, k2), n), work.work("ucm.root", (d,), n)
    for k in range(d):
        scale = np.sqrt(d * np.maximum(vals[k], 0.0))
        np.multiply(vecs[k], scale, out=root)
        np.add(mean, root, out=pts[:, k])
        np.subtract(mean, root, out=pts[:, d + k])
    # predicted variance along the tangent (y, -x) / rho
    tangent = root[:2]
    np.copyto(tangent[0], mean[1])
    np.negative(mean[0], out=tangent[1])
    rho2 = np.einsum("in,in->n", mean[:2], mean[:2])
    var_t = np.einsum("in,ijn,jn->n", tangent, cov[:2, :2], tangent)
    if (rho2 > 0).all():
        var_t /= rho2
    else:
        var_t = np.where(rho2 > 0, var_t / np.maximum(rho2, 1e-300),
                         0.5 * (cov[0, 0] + cov[1, 1]))
    var_az = var_t / np.maximum(rho2, 1e-12)  # predicted azimuth variance, rad^2
    w = var_az / (var_az + saz * saz)
    x, y = pts[0], pts[1]
    az, turn, sin, cos = (work.work(f"ucm.{name}", (k2,), n)
                          for name in ("az", "turn", "sin", "cos"))
    np.arctan2(x, y, out=az)
    np.subtract(az_meas, az, out=turn)
    np.divide(turn, 2 * np.pi, out=sin)
    np.round(sin, out=sin)
    sin *= 2 * np.pi
    turn -= sin  # wrapped to [-pi, pi]
    turn *= w
    az += turn
    # cos and sin of the turned azimuth, as _cos_sin
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
    rho2 = np.einsum("ckn,ckn->kn", pts, pts, out=work.work("ucm.rho2", (k2,), n))
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
    pt = work.work("ucm.pt", (4, k2), n)  # r^2, ce^2, rho2, z^2 of each point
    r2, ce2, rho2, z2 = pt
    inv_r2 = work.work("ucm.ir2", (k2,), n)
    np.einsum("ckn,ckn->kn", pts[:2], pts[:2], out=rho2)
    np.multiply(z, z, out=z2)
    np.add(rho2, z2, out=r2)
    if r2.min() > 0:
        np.divide(1.0, r2, out=inv_r2)
        np.multiply(rho2, inv_r2, out=ce2)
    else:  # el = 0 at the origin, as arctan2
        np.divide(1.0, np.where(r2 > 0, r2, 1.0), out=inv_r2)
        ce2[...] = np.where(r2 > 0, rho2 * inv_r2, 1.0)
    sum_ce2, sum_rho2, sum_z2 = pt[1:].sum(1)
    sum_se2 = np.einsum("kn,kn->n", z2, inv_r2)  # z^2 / r^2
    sum_b = sum_rho2 + sum_z2 + k2 * sr2
    sum_a = sinh_a * (e_el * (sum_rho2 + sr2 * sum_ce2) + sinh_e * sum_b)
    g0, g1 = sr2 * e_el, np.expm1(-s2e)  # g / r^2 = g0 / r^2 + g1
    out[2, 2] = sinh_e * sum_b + g0 * sum_se2 + g1 * sum_z2
    # c = B E(saz) sinh_e + ce^2 sr^2 E(saz) E(sel) + rho2 expm1(-saz^2 - sel^2)
    coef = work.work("ucm.coef", (3,), n)
    np.multiply(e_az, sinh_e, out=coef[0])
    np.multiply(sr2, e_az * e_el, out=coef[1])
    np.expm1(-s2a - s2e, out=coef[2])
    sum_c = coef[0] * sum_b + coef[1] * sum_ce2 + coef[2] * sum_rho2
    c = np.einsum("jn,jkn->kn", coef, pt[:3], out=work.work("ucm.c", (k2,), n))
    c += coef[0] * sr2
    # f = z rho (g0 / r^2 + g1): sums of z rho / r^2 and z rho times sin and cos
    zr = work.work("ucm.zr", (2, k2), n)
    np.sqrt(rho2, out=zr[1])
    zr[1] *= z
    np.multiply(zr[1], inv_r2, out=zr[0])
    fs, fc = np.einsum("jkn,kn->jn", zr, sin), np.einsum("jkn,kn->jn", zr, cos)
    out[0, 2] = g0 * fs[0] + g1 * fs[1]
    out[1, 2] = g0 * fc[0] + g1 * fc[1]
    _horizontal(c, sum_c, sum_a, sin, cos, out)


def _horizontal(c: np.ndarray, sum_c: np.ndarray, sum_a: np.ndarray, sin: np.ndarray,
                cos: np.ndarray, out: np.ndarray) -> None:
    """Sums of the horizontal block a I + c u u' over the points (k, N)."""
    out[0, 1] = np.einsum("kn,kn,kn->n", c, sin, cos)
    out[0, 0] = np.einsum("kn,kn,kn->n", c, sin, sin)
    np.subtract(sum_c, out[0, 0], out=out[1, 1])  # sum of c cos^2
    out[0, 0] += sum_a
    out[1, 1] += sum_a


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
