"""The conversion at the measured points compiled (Numba), apart so that importing
`ucm_jit` does not import Numba: `ucm.cmkf_arrays(batch, None)` is its NumPy form (the
same formulas in the same order, to 1e-12: tests/test_ucm_jit.py) and serves until
this is loaded (`estimation.jit`)."""

from __future__ import annotations

import math

from numba import njit


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
            r[i, 0, 1] = k * lb4 * s2a - p0 * p1
            r[i, 1, 0] = k * lb4 * s2a - p1 * p0
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
