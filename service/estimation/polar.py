"""Polar radar geometry: compass azimuth (docs/protocol.md: x = r cos el sin az,
y = r cos el cos az, z = r sin el; the math-convention bearing is pi/2 - az), the
unbiased converted measurement (UCM) and its error covariance at a known position (Mo,
Song, Zhou, Sun & Bar-Shalom, IEEE TAES 34(3), 1998), and the EKF's linearised terms.
Vectorised over a leading batch axis; the textbook forms that the fast kernels of
`ucm` are tested against.
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


def polar_linearised(rel: np.ndarray, meas: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EKF terms of a polar measurement at predicted sensor-relative positions rel (N, d):
    predicted measurement h(rel) = (r, az[, el]), its Jacobian (N, d, d) with respect to
    the position, and the measurement with its azimuth unwrapped to lie within pi of the
    prediction. Near the zenith the 1/rho^2 azimuth terms blow up: that is the EKF's
    weakness this baseline exists to show (docs/scenarios.md, B)."""
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
