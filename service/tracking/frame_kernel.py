"""The frame's draw compiled (Numba), apart so that importing `frame` does not import
Numba: `frame.draw_plain` is its NumPy form (the same bits, tests/test_frame.py) and
serves until this is loaded (`estimation.jit`)."""

from __future__ import annotations

import math

from numba import njit

from .status import COASTING


@njit(cache=True, nogil=True)
def draw(x, tt, a, base, limit, rows, t, noise, d, o, pos, vel, sigma, age,
         codes):  # pragma: no cover - compiled
    """The columns of store rows `rows` drawn at instant t into row i of the outputs: the
    operations of `display.predicted_at` in its order, one row at a time (the same bits:
    no fast-math, so no operation is fused or reordered)."""
    for i in range(len(rows)):
        r = rows[i]
        dt = t - tt[r]
        if o == 3:  # pos = x0 + dt (v + a dt / 2), vel = v + dt a
            h = dt * 0.5
            for k in range(d):
                pos[i, k] = (x[2 * d + k, r] * h + x[d + k, r]) * dt + x[k, r]
                vel[i, k] = x[2 * d + k, r] * dt + x[d + k, r]
            # A00 + dt (2 A01 + dt (A11 + A02 + dt (A12 + dt A22 / 4)))
            w = ((((a[5, r] * dt + a[4, r]) * dt + a[3, r] + a[2, r]) * dt + a[1, r]) * dt
                 + a[0, r])
            g = dt * dt
            w += g * g * g * noise  # dim q^2 |dt|^6 / 20
        else:
            for k in range(d):
                pos[i, k] = x[d + k, r] * dt + x[k, r]
                vel[i, k] = x[d + k, r]
            w = (a[2, r] * dt + a[1, r]) * dt + a[0, r]  # A00 + dt (2 A01 + dt A11)
            g = dt * dt
            w += g * g * noise  # dim q^2 |dt|^4 / 3
        if w < 0.0:
            w = 0.0
        sigma[i] = math.sqrt(w)
        age[i] = 0.0 if dt < 0.0 else dt
        codes[i] = COASTING if age[i] > limit[r] else base[r]
