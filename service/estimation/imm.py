"""Interacting multiple model filter on converted measurements, vectorised over rows."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import defaults
from . import kalman, models
from .batch import einsum
from .filters import Convert, Result, moments, predict


def standard_modes(q: float = defaults.Q_CV, ct_q: float = defaults.IMM_CT_Q,
                   turn_deg: float = defaults.IMM_TURN_DEG) -> tuple[tuple, ...]:
    """The service's IMM modes (name, kind, q, omega): CV and CA with white noise `q`
    (m/s^2 for CV, m/s^3 for CA) and coordinated turns at +- `turn_deg` deg/s with
    `ct_q` x q."""
    w = np.radians(turn_deg)
    return (("cv", "cv", q, 0.0), ("ca", "ca", q, 0.0),
            ("ct+", "ct", ct_q * q, w), ("ct-", "ct", ct_q * q, -w))


def mix(x: np.ndarray, p: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The IMM's mixing step: x0_j = sum_i w_ij x_i and
    P0_j = sum_i w_ij (P_i + (x_i - x0_j)(x_i - x0_j)') for x (N, M, n), P (N, M, n, n),
    w (N, M, M) (Bar-Shalom, Li & Kirubarajan 2001, sec. 11.6.6, step 1).

    Evaluated as sum_i w_ij (P_i + y_i y_i') - y0_j y0_j' on the states relative to mode
    0 (y_i = x_i - x_0, y0_j = x0_j - x_0; the weights of each j sum to 1): no
    (N, M, M, n, n) temporary (100 MB at 10,000 rows of the 4-mode order-3 IMM, 1.1 s of
    an update), and the differences are small, so the subtraction keeps its digits
    (`reference.imm_mix` is the textbook form; tests/test_reference.py)."""
    ref = x[:, :1]
    y = x - ref
    y0 = np.einsum("nij,nix->njx", w, y)
    second = p + y[..., :, None] * y[..., None, :]
    p0 = np.einsum("nij,nixy->njxy", w, second) - y0[..., :, None] * y0[..., None, :]
    return y0 + ref, p0


@dataclass(frozen=True)
class IMM:
    """Interacting multiple model filter (Blom & Bar-Shalom 1988; Bar-Shalom, Li &
    Kirubarajan 2001, sec. 11.6.6) on converted measurements, vectorised over rows.

    `modes` are (name, kind, q, omega) in a padded order-3 state. Mode switching is a
    Markov chain whose staying probability over a step dt is exp(-dt / sojourn), the rest
    spread evenly, so irregular scan intervals are handled.
    """

    modes: Sequence[tuple[str, str, float, float]] = field(
        default_factory=lambda: standard_modes())
    sojourn: float = defaults.IMM_SOJOURN
    order: int = 3

    @property
    def fields(self) -> dict[str, tuple]:
        """Per-row arrays kept in the track store: each mode's state, covariance and
        probability."""
        m = len(self.modes)
        return {"mode_x": ("n", m), "mode_p": ("nn", m), "mode_prob": ("", m)}

    def initiate(self, arrays: Any, rows: np.ndarray) -> None:
        arrays.mode_x[rows] = arrays.x[rows, None]
        arrays.mode_p[rows] = arrays.p[rows, None]
        arrays.mode_prob[rows] = 1.0 / len(self.modes)

    def transition(self, dt: np.ndarray) -> np.ndarray:
        m = len(self.modes)
        stay = np.exp(-np.abs(dt) / self.sojourn)
        pi = np.repeat(((1 - stay) / (m - 1))[:, None, None], m, 1).repeat(m, 2)
        idx = np.arange(m)
        pi[:, idx, idx] = stay[:, None]
        return pi

    def update(self, arrays: Any, rows: np.ndarray, dt: np.ndarray, convert: Convert) -> Result:
        mx, mp, mu = arrays.mode_x[rows], arrays.mode_p[rows], arrays.mode_prob[rows]
        pi = self.transition(dt)  # pi[n, i, j] = P(mode j next | mode i now)
        c = einsum("nij,ni->nj", pi, mu)  # predicted mode probabilities
        w = pi * mu[:, :, None] / np.maximum(c[:, None, :], 1e-300)  # mixing mu_{i|j}
        x0 = einsum("nij,nix->njx", w, mx)
        d = mx[:, :, None, :] - x0[:, None, :, :]  # (N, i, j, n)
        p0 = einsum("nij,nijxy->njxy", w, mp[:, :, None] + d[..., :, None] * d[..., None, :])
        xps, pps = [], []
        for j, (_, kind, q, omega) in enumerate(self.modes):
            f, qm = models.motion(kind, dt, self.order, arrays.dim, q, omega)
            xp, pp = predict(x0[:, j], p0[:, j], f, qm)
            xps.append(xp)
            pps.append(pp)
        xp, pp = np.stack(xps, 1), np.stack(pps, 1)
        xbar, pbar = moments(xp, pp, c)
        conv = convert(xbar, pbar)  # one conversion, at the mixture's prediction
        outs = [kalman.update_full(xp[:, j], pp[:, j], *conv) for j in range(len(self.modes))]
        xu = np.stack([o[0] for o in outs], 1)
        pu = np.stack([o[1] for o in outs], 1)
        loglik = np.stack([o[4] for o in outs], 1)
        ok = np.all([o[3] for o in outs], 0)
        logw = np.log(np.maximum(c, 1e-300)) + loglik
        logw -= logw.max(1, keepdims=True)
        mu_new = np.exp(logw)
        mu_new /= mu_new.sum(1, keepdims=True)
        ok &= np.isfinite(mu_new).all(1)
        good = rows[ok]
        arrays.mode_x[good], arrays.mode_p[good] = xu[ok], pu[ok]
        arrays.mode_prob[good] = mu_new[ok]
        x, p = moments(xu, pu, np.where(np.isfinite(mu_new), mu_new, 0.0))
        _, _, nis, _ = kalman.update(xbar, pbar, *conv)  # NIS of the mixture prediction
        return x, p, nis, ok

    def inflate(self, arrays: Any, rows: np.ndarray, dp: np.ndarray) -> None:
        """The tracker added dp to the combined covariances of rows (the spread of a PDA
        update): every mode's covariance takes it too."""
        arrays.mode_p[rows] += dp[:, None]

    def labels(self, arrays: Any, rows: np.ndarray) -> list[dict[str, float]]:
        names = [name for name, *_ in self.modes]
        return [dict(zip(names, mu, strict=True)) for mu in arrays.mode_prob[rows].tolist()]
