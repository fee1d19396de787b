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
    bad = ~np.isfinite(cov).all((1, 2))
    vals, vecs = np.linalg.eigh(np.where(bad[:, None, None], 0.0, cov))
    root = vecs * np.sqrt(np.maximum(vals, 0.0))[:, None, :]  # root @ root' = cov, PSD-safe
    offsets = np.sqrt(d) * np.concatenate([root, -root], axis=2).transpose(0, 2, 1)
    points = (mean[:, None, :] + offsets).reshape(n * 2 * d, d)

    def rep(a: np.ndarray) -> np.ndarray:
        return np.repeat(a, 2 * d)

    x, y = mean[:, 0], mean[:, 1]
    rho2 = x**2 + y**2
    tangent = np.stack([y, -x], 1) / np.sqrt(np.maximum(rho2, 1e-300))[:, None]
    var_t = np.where(rho2 > 0, np.einsum("ni,nij,nj->n", tangent, cov[:, :2, :2], tangent),
                     0.5 * np.trace(cov[:, :2, :2], axis1=1, axis2=2))
    var_az = var_t / np.maximum(rho2, 1e-12)  # predicted azimuth variance, rad^2
    w = rep(var_az / (var_az + saz**2))
    r, az, el = cartesian_to_polar(points)
    az = az + w * np.angle(np.exp(1j * (rep(az_meas) - az)))
    r = ucm_covariance_polar(r, az, el, rep(sr), rep(saz), None if sel is None else rep(sel))
    r = r.reshape(n, 2 * d, d, d).mean(axis=1)
    r[bad] = np.nan  # flagged by the caller's finiteness check
    return r


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
