"""Filters over a bank of tracks: how one batch of rows is predicted and updated.

Every filter works on stacked arrays (rows of a `Bank`) and returns the output estimate
(x, P) of each row; the track table stores it and predicts it for display. `Single` is
one model (CMKF, or the EKF baseline); `IMM` mixes several models; `VDF` switches between
CV and CA on a manoeuvre detector. Pure NumPy, no Zenoh.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import convert as conversion
from . import kalman, models, work

# (x_pred (N, n), P_pred (N, n, n)) -> (z, R[, h, hx]) converted for those predictions
Convert = Callable[[np.ndarray, np.ndarray], tuple]
Result = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # x, P, nis, ok


@dataclass
class Single:
    """One motion model ("cv" or "ca") with the CMKF, or the EKF on polar input."""

    kind: str = "cv"
    q: float = 1.0
    order: int = 2
    fields: dict[str, tuple] = field(default_factory=dict)

    def initiate(self, bank: Any, rows: np.ndarray) -> None:
        """Nothing beyond the table's own x and P."""

    def update(self, bank: Any, rows: np.ndarray, dt: np.ndarray, convert: Convert) -> Result:
        standard = (self.kind, self.order) in (("cv", 2), ("ca", 3))  # F, Q of models.predict
        if standard and isinstance(convert, conversion.CMKFConversion):
            return cmkf_step(bank.x[rows], bank.p[rows], dt, self.order, bank.dim, self.q,
                             convert.batch)
        if standard:
            xp, pp = models.predict(bank.x[rows], bank.p[rows], dt, self.order, bank.dim,
                                    self.q)
        else:
            f, qm = models.motion(self.kind, dt, self.order, bank.dim, self.q)
            xp, pp = predict(bank.x[rows], bank.p[rows], f, qm)
        return kalman.update(xp, pp, *convert(xp, pp))

    def labels(self, bank: Any, rows: np.ndarray) -> list[str | dict[str, float]]:
        return [self.kind] * len(rows)


def cmkf_step(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
              q: float | np.ndarray, batch: conversion.MeasurementBatch) -> Result:
    """The filter core: prediction (`models.predict_soa`), conversion of the measurements
    at the prediction (`convert.cmkf_soa`) and CMKF update (`kalman.update_soa`) of rows
    x (N, n), P (N, n, n) over their own dt, in one pass per chunk of rows on batch-last
    work arrays. Returns new arrays: posterior x, P, NIS and the mask of finite rows."""
    n_rows, n = x.shape
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (n_rows,))
    q = np.asarray(q, dtype=float)
    xn, pn = np.empty((n_rows, n)), np.empty((n_rows, n, n))
    nis, det, ok = np.empty(n_rows), np.empty(n_rows), np.empty(n_rows, dtype=bool)
    for lo, hi in work.chunks(n_rows):
        k = hi - lo
        xs, ps = work.to_soa(x[lo:hi], "step.x"), work.to_soa(p[lo:hi], "step.p")
        models.predict_soa(xs, ps, dt[lo:hi], order, dim, q[lo:hi] if q.ndim else q)
        zs, rs = work.work("step.z", (dim,), k), work.work("step.r", (dim, dim), k)
        conversion.cmkf_soa(batch.rows(lo, hi), xs[:dim], ps[:dim, :dim], zs, rs)
        pout = work.work("step.pn", (n, n), k)
        kalman.update_soa(xs, ps, zs, rs, pout, nis[lo:hi], det[lo:hi])
        ok[lo:hi] = kalman.finite(xs, pout, nis[lo:hi], dim)
        np.copyto(xn[lo:hi].T, xs)
        np.copyto(np.moveaxis(pn[lo:hi], 0, -1), pout)
    return xn, pn, nis, ok


def predict(x: np.ndarray, p: np.ndarray, f: np.ndarray, q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """x (N, n), P (N, n, n) predicted by full transition matrices F and noise Q (N, n, n)."""
    xp = (f @ x[:, :, None])[:, :, 0]  # matmul: much faster than einsum on small matrices
    return xp, kalman.symmetrise(f @ p @ f.transpose(0, 2, 1) + q)


def moments(x: np.ndarray, p: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of Gaussian mixtures: x (N, M, n), P (N, M, n, n), w (N, M)."""
    mean = np.einsum("nm,nmi->ni", w, x)
    d = x - mean[:, None]
    cov = np.einsum("nm,nmij->nij", w, p + d[..., :, None] * d[..., None, :])
    return mean, kalman.symmetrise(cov)


@dataclass
class IMM:
    """Interacting multiple model filter (Blom & Bar-Shalom 1988; Bar-Shalom, Li &
    Kirubarajan 2001, sec. 11.6.6) on converted measurements, vectorised over rows.

    `modes` are (name, kind, q, omega) in a padded order-3 state. Mode switching is a
    Markov chain whose staying probability over a step dt is exp(-dt / sojourn), the rest
    spread evenly, so irregular scan intervals are handled.
    """

    modes: Sequence[tuple[str, str, float, float]] = (
        ("cv", "cv", 0.05, 0.0), ("ca", "ca", 0.01, 0.0),
        ("ct+", "ct", 0.05, np.radians(1.5)), ("ct-", "ct", 0.05, -np.radians(1.5)))
    sojourn: float = 40.0
    order: int = 3
    fields: dict[str, tuple] = field(default_factory=dict)

    def __post_init__(self) -> None:
        m = len(self.modes)
        self.fields = {"mx": ("n", m), "mp": ("nn", m), "mu": ("", m)}

    def initiate(self, bank: Any, rows: np.ndarray) -> None:
        bank.mx[rows] = bank.x[rows, None]
        bank.mp[rows] = bank.p[rows, None]
        bank.mu[rows] = 1.0 / len(self.modes)

    def transition(self, dt: np.ndarray) -> np.ndarray:
        m = len(self.modes)
        stay = np.exp(-np.abs(dt) / self.sojourn)
        pi = np.repeat(((1 - stay) / (m - 1))[:, None, None], m, 1).repeat(m, 2)
        idx = np.arange(m)
        pi[:, idx, idx] = stay[:, None]
        return pi

    def update(self, bank: Any, rows: np.ndarray, dt: np.ndarray, convert: Convert) -> Result:
        mx, mp, mu = bank.mx[rows], bank.mp[rows], bank.mu[rows]
        pi = self.transition(dt)  # pi[n, i, j] = P(mode j next | mode i now)
        c = np.einsum("nij,ni->nj", pi, mu)  # predicted mode probabilities
        w = pi * mu[:, :, None] / np.maximum(c[:, None, :], 1e-300)  # mixing mu_{i|j}
        x0 = np.einsum("nij,nix->njx", w, mx)
        d = mx[:, :, None, :] - x0[:, None, :, :]  # (N, i, j, n)
        p0 = np.einsum("nij,nijxy->njxy", w, mp[:, :, None] + d[..., :, None] * d[..., None, :])
        xps, pps = [], []
        for j, (_, kind, q, omega) in enumerate(self.modes):
            f, qm = models.motion(kind, dt, self.order, bank.dim, q, omega)
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
        bank.mx[good], bank.mp[good], bank.mu[good] = xu[ok], pu[ok], mu_new[ok]
        x, p = moments(xu, pu, np.where(np.isfinite(mu_new), mu_new, 0.0))
        _, _, nis, _ = kalman.update(xbar, pbar, *conv)  # NIS of the mixture prediction
        return x, p, nis, ok

    def labels(self, bank: Any, rows: np.ndarray) -> list[dict[str, float]]:
        names = [name for name, *_ in self.modes]
        return [dict(zip(names, mu, strict=True)) for mu in bank.mu[rows].tolist()]


@dataclass
class VDF:
    """Variable-dimension filter (Bar-Shalom & Birmiwal, IEEE TAES 18(5), 1982; Bar-Shalom,
    Li & Kirubarajan 2001, sec. 11.4), as scenario C specifies it.

    CV with zero process noise while quiet; the fading-memory sum rho = alpha rho + NIS
    above `detect` declares a manoeuvre, and the track is re-estimated with the CA model
    over the detection window (the last `window` updates, restarted from the CV estimate
    before them with a wide acceleration prior). In CA, the acceleration's process noise
    std is `ca_noise` x |acceleration estimate|; the fading sum of a' P_aa^-1 a below
    `settle` returns the track to CV. Tracks start in CA; the detector is armed when they
    first return to CV.
    """

    alpha: float = 0.8
    detect: float = 35.0
    settle: float = 13.0
    ca_noise: float = 0.05
    accel_prior: float = 1.0  # m/s^2, std of the acceleration at a CA restart
    window: int = 5
    order: int = 3
    fields: dict[str, tuple] = field(default_factory=dict)

    def __post_init__(self) -> None:
        w = self.window + 1
        self.fields = {"ca": ("", None), "armed": ("", None), "rho": ("", None),
                       "hx": ("n", w), "hp": ("nn", w), "hz": ("d", w), "hr": ("dd", w),
                       "ht": ("", w), "hcount": ("", None)}

    def initiate(self, bank: Any, rows: np.ndarray) -> None:
        bank.ca[rows], bank.armed[rows], bank.rho[rows], bank.hcount[rows] = 1, 0, 0.0, 0
        self._remember(bank, rows, bank.x[rows], bank.p[rows], None, None, bank.t[rows])

    def _remember(self, bank: Any, rows: np.ndarray, x: np.ndarray, p: np.ndarray,
                  z: np.ndarray | None, r: np.ndarray | None, t: np.ndarray) -> None:
        """Shift the per-track history (oldest first) and append this update."""
        for name, v in (("hx", x), ("hp", p), ("hz", z), ("hr", r), ("ht", t)):
            a = getattr(bank, name)
            a[rows, :-1] = a[rows, 1:]
            a[rows, -1] = np.nan if v is None else v
        bank.hcount[rows] += 1

    def update(self, bank: Any, rows: np.ndarray, dt: np.ndarray, convert: Convert) -> Result:
        d = bank.dim
        x, p = bank.x[rows].copy(), bank.p[rows].copy()
        ca = bank.ca[rows].astype(bool)
        f_cv, q_cv = models.motion("cv", dt, 3, d, 0.0)
        xp, pp = predict(x, p, f_cv, q_cv)
        if ca.any():
            acc = np.linalg.norm(x[ca, 2 * d:], axis=1)
            qa = self.ca_noise * acc / np.maximum(np.abs(dt[ca]), 1e-9)
            f, qm = models.motion("ca", dt[ca], 3, d, qa)
            xp[ca], pp[ca] = predict(x[ca], p[ca], f, qm)
        z, r = convert(xp, pp)
        xn, pn, nis, ok = kalman.update(xp, pp, z, r)
        # manoeuvre detector (CV tracks) and acceleration significance (CA tracks)
        rho = self.alpha * bank.rho[rows] + np.where(ok, nis, 0.0)
        a = xn[:, 2 * d:]
        paa = pn[:, 2 * d:, 2 * d:] + 1e-12 * np.eye(d)
        sig = np.einsum("ni,ni->n", a, kalman.solve(paa, a[:, :, None])[:, :, 0])
        rho = np.where(ca, self.alpha * bank.rho[rows] + np.where(ok, sig, 0.0), rho)
        good = rows[ok]
        self._remember(bank, good, xn[ok], pn[ok], z[ok], r[ok], bank.t[good] + dt[ok])
        bank.rho[good] = rho[ok]
        # CA -> CV: acceleration no longer significant; arms the detector
        settle = ok & ca & (rho < self.settle)
        if settle.any():
            xn[settle, 2 * d:] = 0.0
            pn[settle, 2 * d:, :] = 0.0
            pn[settle, :, 2 * d:] = 0.0
            s_rows = rows[settle]
            bank.ca[s_rows], bank.armed[s_rows], bank.rho[s_rows] = 0, 1, 0.0
        # CV -> CA: manoeuvre detected; re-estimate over the detection window
        onset = ok & ~ca & (bank.armed[rows] > 0) & (rho > self.detect) & \
            (bank.hcount[rows] > self.window + 1)
        if onset.any():
            xr, pr = self._restart(bank, rows[onset])
            xn[onset], pn[onset] = xr, pr
            o_rows = rows[onset]
            bank.ca[o_rows], bank.rho[o_rows] = 1, 0.0
        return xn, pn, nis, ok

    def _restart(self, bank: Any, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CA from the CV estimate before the window, re-run over the window's measurements."""
        d = bank.dim
        x = bank.hx[rows, 0].copy()
        p = bank.hp[rows, 0].copy()
        p[:, 2 * d:, 2 * d:] += self.accel_prior**2 * np.eye(d)
        t = bank.ht[rows, 0]
        for k in range(1, self.window + 1):
            tk = bank.ht[rows, k]
            f, qm = models.motion("ca", tk - t, 3, d, 0.0)
            xp, pp = predict(x, p, f, qm)
            x, p, _, _ = kalman.update(xp, pp, bank.hz[rows, k], bank.hr[rows, k])
            t = tk
        return x, p

    def labels(self, bank: Any, rows: np.ndarray) -> list[str]:
        return ["ca" if ca else "cv" for ca in bank.ca[rows].tolist()]
