"""The 3-D coordinated turn at the rate of the state's own velocity and acceleration
(Watson & Blair, SPIE 1698, 1992; Li & Jilkov, IEEE TAES 39(4), 2003, sec. 5.3): no
extra state, the CA model when the acceleration is along the velocity; an EKF, its
Jacobian through the rate (docs/accuracy.md, "a turn-rate filter"). `imm_kernel`'s
"turn" kind is its compiled form (tests/test_imm_jit.py).
"""

from __future__ import annotations

import numpy as np

from .models import axis_transition, expand

# |omega dt| below which the turn's Q and dPhi/domega are their series to (omega dt)^4
# (Taylor's, relative error under 1e-6; the closed forms lose ~1e-12 just above it)
TURN_SMALL = 0.2


def _cross(x: np.ndarray, dim: int) -> tuple[np.ndarray, ...]:
    """v, a (N, 3; a 2-D state's padded with 0), c = v x a, |c| and |v|^2 of states x."""
    v, a = x[:, dim:2 * dim], x[:, 2 * dim:3 * dim]
    if dim == 2:
        v, a = np.pad(v, ((0, 0), (0, 1))), np.pad(a, ((0, 0), (0, 1)))
    c = np.cross(v, a)
    return v, a, c, np.linalg.norm(c, axis=1), np.einsum("na,na->n", v, v)


def turn_rate(x: np.ndarray, dim: int, cap: float) -> np.ndarray:
    """The turn rate (N,) of order-3 states x (N, 3 dim) for the "turn" model:
    |v x a| / |v|^2 (Watson & Blair, SPIE 1698, 1992: a coordinated turn's rate from its
    velocity and acceleration; the acceleration along v does not turn it), at most `cap`
    rad/s; 0 below 1 m/s."""
    *_, n, s = _cross(x, dim)
    return np.where(s > 1.0, np.minimum(n / np.maximum(s, 1.0), cap), 0.0)


def turn_axis(dt: np.ndarray, omega: np.ndarray, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis Phi and Q (N, 3, 3) of the 3-D coordinated turn with the rate in the
    state's velocity and acceleration (Watson & Blair 1992; Li & Jilkov, IEEE TAES 39(4),
    2003, sec. 5.3): da/dt = -omega^2 v + white jerk of density q^2, the same on every
    axis, so F = kron(Phi, I); Q is that noise (of density q^2 |dt| as `noise_terms`)
    integrated exactly over |dt| (`turn_noise_series` when |omega dt| < `TURN_SMALL`).
    omega = 0 is the CA model."""
    t = np.asarray(dt, dtype=float) * np.ones_like(omega)
    w = np.asarray(omega, dtype=float) * np.ones_like(t)
    ws = np.where(w == 0.0, 1.0, w)
    x = w * t
    s, c, h = np.sin(x), np.cos(x), np.sin(0.5 * x)
    phi = axis_transition(t, 3)
    turning = w != 0.0
    phi[..., 0, 1] = np.where(turning, s / ws, t)
    phi[..., 0, 2] = np.where(turning, 2.0 * h * h / ws ** 2, 0.5 * t * t)
    phi[..., 1, 1] = c
    phi[..., 1, 2] = np.where(turning, s / ws, t)
    phi[..., 2, 1] = -w * s
    phi[..., 2, 2] = c
    at = np.abs(t)
    qm = turn_noise_series(at, w)
    y = w * at
    big = np.abs(y) >= TURN_SMALL
    if big.any():
        T, W, y = at[big], ws[big], y[big]
        s1, s2 = np.sin(y), np.sin(2 * y)
        e = np.empty((len(T), 3, 3))
        e[:, 0, 0] = (1.5 * T - 2 * s1 / W + s2 / (4 * W)) / W ** 4
        e[:, 0, 1] = (2 * np.sin(0.5 * y) ** 2 - 0.5 * s1 ** 2) / W ** 4
        e[:, 0, 2] = (s1 / W - 0.5 * T - s2 / (4 * W)) / W ** 2
        e[:, 1, 1] = (0.5 * T - s2 / (4 * W)) / W ** 2
        e[:, 1, 2] = 0.5 * s1 ** 2 / W ** 2
        e[:, 2, 2] = 0.5 * T + s2 / (4 * W)
        for a, b in ((1, 0), (2, 0), (2, 1)):
            e[:, a, b] = e[:, b, a]
        qm[big] = e * T[:, None, None]  # the density q^2 |dt| of `noise_terms`
    return phi, qm * q * q


def turn_noise_series(at: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The turn's Q per unit q^2 (N, 3, 3) over |dt| = at: the integral of g g' with
    g(s) = [(1 - cos ws) / w^2, sin(ws) / w, cos ws], expanded to w^4 (the CA's at w = 0),
    times the density's |dt|."""
    t2, w2 = at * at, w * w
    w4 = w2 * w2
    out = np.empty(np.shape(at) + (3, 3))
    out[..., 0, 0] = t2 * t2 * at * (1 / 20 - w2 * t2 / 168 + w4 * t2 * t2 / 2880)
    out[..., 0, 1] = t2 * t2 * (1 / 8 - w2 * t2 / 48 + w4 * t2 * t2 / 640)
    out[..., 0, 2] = t2 * at * (1 / 6 - 7 * w2 * t2 / 120 + 31 * w4 * t2 * t2 / 5040)
    out[..., 1, 1] = t2 * at * (1 / 3 - w2 * t2 / 15 + 2 * w4 * t2 * t2 / 315)
    out[..., 1, 2] = t2 * (1 / 2 - w2 * t2 / 6 + w4 * t2 * t2 / 45)
    out[..., 2, 2] = at * (1 - w2 * t2 / 3 + w4 * t2 * t2 / 15)
    for a, b in ((1, 0), (2, 0), (2, 1)):
        out[..., a, b] = out[..., b, a]
    return out * at[..., None, None]


def turn_model(x: np.ndarray, dt: np.ndarray, dim: int, q: float, cap: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """F, Q and the Jacobian J (N, n, n) of the "turn" model from the states x (N, 3 dim):
    the prediction is F(omega(x)) x with omega = `turn_rate`, so its covariance takes
    J = F + (dF/domega x)(domega/dx)' (an EKF: without the rate's dependence on v and a
    the filter diverges in a steady turn at low noise; docs/accuracy.md)."""
    omega = turn_rate(x, dim, cap)
    phi, qm = turn_axis(np.atleast_1d(dt), omega, q)
    f = expand(phi, dim)
    t = np.asarray(dt, dtype=float) * np.ones(len(x))
    w = omega
    y = w * t
    ws = np.where(w == 0.0, 1.0, w)
    s, c = np.sin(y), np.cos(y)
    small = np.abs(y) < TURN_SMALL
    dphi = np.zeros((len(x), 3, 3))  # dPhi / domega
    w3 = w * w * w  # the series to (omega dt)^4 below TURN_SMALL
    dphi[:, 0, 1] = np.where(small, -w * t ** 3 / 3 + w3 * t ** 5 / 30, (y * c - s) / ws ** 2)
    dphi[:, 0, 2] = np.where(small, -w * t ** 4 / 12 + w3 * t ** 6 / 180,
                             (y * s - 2 * (1 - c)) / ws ** 3)
    dphi[:, 1, 1] = dphi[:, 2, 2] = -t * s
    dphi[:, 1, 2] = dphi[:, 0, 1]
    dphi[:, 2, 1] = -s - y * c
    g = (expand(dphi, dim) @ x[:, :, None])[:, :, 0]
    jac = f + g[:, :, None] * turn_rate_gradient(x, dim, cap)[:, None, :]
    return f, expand(qm, dim), jac


def turn_rate_gradient(x: np.ndarray, dim: int, cap: float) -> np.ndarray:
    """d `turn_rate` / dx (N, 3 dim): with c = v x a, n = |c|, s = |v|^2, omega = n / s,
    dn/dv = (a x c) / n, dn/da = (c x v) / n; 0 where the rate is capped, below 1 m/s or
    n = 0 (a along v: no turn)."""
    v, a, c, n, s = _cross(x, dim)
    live = (s > 1.0) & (n > 1e-12 * np.maximum(s, 1.0)) & (n / np.maximum(s, 1.0) < cap)
    ns = np.where(live, n * s, 1.0)
    out = np.zeros((len(x), 3 * dim))
    dv = np.cross(a, c) / ns[:, None] - (2 * n / np.where(live, s * s, 1.0))[:, None] * v
    da = np.cross(c, v) / ns[:, None]
    out[:, dim:2 * dim] = np.where(live[:, None], dv[:, :dim], 0.0)
    out[:, 2 * dim:] = np.where(live[:, None], da[:, :dim], 0.0)
    return out
