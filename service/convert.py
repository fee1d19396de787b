"""Measurement conversion: polar radar measurements to Cartesian points with covariance.

Unbiased converted measurement (UCM, Mo, Song, Zhou, Sun & Bar-Shalom, IEEE TAES
34(3), 1998) with its error covariance evaluated at the predicted position, which keeps
the gain uncorrelated with the measurement error (Bordonaro, Willett & Bar-Shalom,
IEEE TAES 50(2), 2014). Formulas rewritten for the compass azimuth of PROTOCOL.md
(x = r cos el sin az, y = r cos el cos az): the math-convention bearing is pi/2 - az.
All functions are vectorised over a leading batch axis.
"""

from __future__ import annotations

import numpy as np


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


def _eigh(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (N, d) and unit eigenvectors (columns, N x d x d) of symmetric PSD
    matrices, those of `np.linalg.eigh` up to order and signs (and the choice of basis of a
    repeated eigenvalue), in closed form for d <= 3.

    A Jacobi rotation by 0.5 atan2(2 a01, a00 - a11) diagonalises a 2 x 2 block (Golub &
    Van Loan 2013, sec. 8.5.2). For d = 3, the eigenvalue farthest from the other two
    (trigonometric solution of the characteristic cubic: Smith, CACM 4(4), 1961) has its
    eigenvector v along the largest cross product of two rows of cov - lambda I, and a
    Jacobi rotation in the plane orthogonal to v (basis of Duff et al., JCGT 6(1), 2017)
    gives the other two, accurately even when their eigenvalues are close. Per-entry
    arithmetic on (N,) arrays; the vectors are views of a (d, d, N) array."""
    n, d = cov.shape[:2]
    if d > 3:
        return np.linalg.eigh(cov)
    a = {(i, j): cov[:, min(i, j), max(i, j)] for i in range(d) for j in range(d)}

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
        vals, vecs = [a[0, 0]], [[one]]
    elif d == 2:
        vals, vecs = rotate([one, zero], [zero, one])
    else:
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
        vals, vecs = [iso, *pair_vals], [v, *pair_vecs]
    return np.array(vals).T, np.array(vecs).transpose(2, 1, 0)


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
    (sensor-relative), given the measured azimuth.

    R depends on where the target truly is, which only the prediction tells: averaging
    R(p) over the prediction (2d-point spherical cubature, Arasaratnam & Haykin, IEEE TAC
    54(6), 2009) instead of taking R(mean) keeps the filter consistent where R changes
    fast across the predicted region: near the zenith, the overhead pass of scenario B.
    There the prediction hardly knows the azimuth, which orients R, while the measured
    azimuth knows it well; so each cubature point's azimuth is moved toward the measured
    one by the weight w = var_pred / (var_pred + saz^2) of a scalar fusion of the two.
    Far from the zenith w ~ 0 and R keeps no dependence on the measurement error (the
    decorrelation of Bordonaro, Willett & Bar-Shalom, IEEE TAES 50(2), 2014).
    """
    n, d = mean.shape
    bad = ~np.isfinite(cov.reshape(n, -1) @ np.ones(d * d))  # a non-finite entry (or overflow)
    vals, vecs = _eigh(np.where(bad[:, None, None], 0.0, cov) if bad.any() else cov)
    # the 2d points mean +- sqrt(d lambda_k) v_k, coordinate-major: pts[i] (2d, N)
    root = vecs.transpose(1, 2, 0) * np.sqrt(d * np.maximum(vals, 0.0)).T
    pts = mean.T[:, None, :] + np.concatenate([root, -root], 1)
    x, y = mean[:, 0], mean[:, 1]
    rho2 = x**2 + y**2
    cxx, cxy, cyy = cov[:, 0, 0], cov[:, 0, 1] + cov[:, 1, 0], cov[:, 1, 1]
    var_t = np.where(rho2 > 0, (y**2 * cxx - x * y * cxy + x**2 * cyy) / np.maximum(rho2, 1e-300),
                     0.5 * (cxx + cyy))  # along the tangent (y, -x) / rho
    var_az = var_t / np.maximum(rho2, 1e-12)  # predicted azimuth variance, rad^2
    w = var_az / (var_az + saz**2)
    x, y = pts[0], pts[1]
    az = np.arctan2(x, y)
    turn = az_meas - az
    turn -= 2 * np.pi * np.round(turn / (2 * np.pi))  # wrapped to [-pi, pi]
    turn *= w
    cos_az, sin_az = _cos_sin(np.add(az, turn, out=az))
    del turn
    a, c, f, vert = _ucm_terms(x**2 + y**2, pts[2] if d == 3 else None, sr, saz, sel)
    out = np.empty((d, d, n))
    out[0, 0] = (a + c * sin_az**2).mean(0)
    out[1, 1] = (a + c * cos_az**2).mean(0)
    out[0, 1] = out[1, 0] = (c * sin_az * cos_az).mean(0)
    if d == 3:
        out[0, 2] = out[2, 0] = (f * sin_az).mean(0)
        out[1, 2] = out[2, 1] = (f * cos_az).mean(0)
        out[2, 2] = vert.mean(0)
    out[:, :, bad] = np.nan  # flagged by the caller's finiteness check
    return out.transpose(2, 0, 1).copy()


def _ucm_terms(rho2: np.ndarray, z: np.ndarray | None, sr: np.ndarray, saz: np.ndarray,
               sel: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                                np.ndarray | None]:
    """`ucm_covariance_polar` (Mo et al. 1998) regrouped without its O(r^2) cancellation,
    at points of horizontal range^2 rho2 and height z (2d, N): with u = (sin az, cos az) the unit
    horizontal range vector, B = r^2 + sr^2 and E(s) = exp(-s^2), in 2-D
    R = a I + c u u', a = B sinh(saz^2), c = sr^2 E(saz) - r^2 (1 - E(saz)).
    In 3-D, with ce, se the cos and sin of the elevation, the horizontal block is a I + c u u'
    with a = B sinh(saz^2) (sinh(sel^2) + E(sel) ce^2) and
    c = B E(saz) sinh(sel^2) + ce^2 (sr^2 E(saz) E(sel) - r^2 (1 - E(saz) E(sel))); the
    horizontal-vertical block is f u, f = se ce g, and the vertical B sinh(sel^2) + se^2 g,
    with g = sr^2 E(sel) - r^2 (1 - E(sel)). Returns a, c, f, vert (f, vert None in 2-D)."""
    sr2, s2a = sr**2, saz**2
    if z is None:
        return (rho2 + sr2) * np.sinh(s2a), sr2 * np.exp(-s2a) + rho2 * np.expm1(-s2a), None, None
    s2e = sel**2
    sinh_a, sinh_e, e_az, e_el = np.sinh(s2a), np.sinh(s2e), np.exp(-s2a), np.exp(-s2e)
    z2 = z**2
    big_b = rho2 + z2  # r^2 for now
    inv_r2 = 1 / np.where(big_b > 0, big_b, 1.0)
    ce2 = np.where(big_b > 0, rho2 * inv_r2, 1.0)  # el = 0 at the origin, as arctan2
    big_b += sr2
    a = big_b * (sinh_a * e_el) * ce2
    a += big_b * (sinh_a * sinh_e)
    c = big_b * (e_az * sinh_e) + ce2 * (sr2 * e_az * e_el) + rho2 * np.expm1(-s2a - s2e)
    g = inv_r2 * (sr2 * e_el) + np.expm1(-s2e)  # g / r^2
    del inv_r2, ce2
    vert = big_b * sinh_e + z2 * g
    g *= z * np.sqrt(rho2)
    return a, c, g, vert


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
