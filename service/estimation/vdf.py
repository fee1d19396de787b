"""Variable-dimension filter (scenario C's method), vectorised over rows."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .. import defaults
from . import kalman, models
from .batch import einsum
from .filters import Convert, Result, Rows, predict


@dataclass(frozen=True)
class VDF:
    """Variable-dimension filter (Bar-Shalom & Birmiwal, IEEE TAES 18(5), 1982; Bar-Shalom,
    Li & Kirubarajan 2001, sec. 11.4), as scenario C specifies it.

    CV with (nearly) zero process noise while quiet; the fading-memory sum rho = alpha rho + NIS
    above `detect` declares a manoeuvre, and the track is re-estimated with the CA model
    over the detection window (the last `window` updates, restarted from the CV estimate
    before them with a wide acceleration prior). In CA, the acceleration's process noise
    std is `ca_noise` x |acceleration estimate|; the fading sum of a' P_aa^-1 a below
    `settle` returns the track to CV. Tracks start in CA; the detector is armed when they
    first return to CV.

    The paper's CV noise is zero; `cv_noise` (m/s^2, `models`) keeps a trace of it:
    with none, a zero measurement variance drives the covariance to zero and the filter
    stops reading its measurements, and with any the closed loop has a steady state
    inside the unit circle (docs/accuracy.md, "Exact positions"). The CA noise is the
    paper's per step: an acceleration increment of std `ca_noise` x |a| over each step.
    """

    gate_prediction: ClassVar[None] = None  # gated with its state and the display's q

    alpha: float = 0.8
    detect: float = defaults.VDF_DETECT
    settle: float = defaults.VDF_SETTLE
    ca_noise: float = 0.05
    cv_noise: float = 1e-3
    accel_prior: float = 1.0  # m/s^2, std of the acceleration at a CA restart
    window: int = 5
    order: int = 3

    @property
    def fields(self) -> dict[str, tuple]:
        """Per-row arrays kept in the track store: the model in use, the detector's
        state, and the last `window` + 1 updates (for the CA restart)."""
        w = self.window + 1
        return {"ca": ("", None), "armed": ("", None), "rho": ("", None),
                       "hist_x": ("n", w), "hist_p": ("nn", w), "hist_z": ("d", w),
                       "hist_r": ("dd", w), "hist_t": ("", w), "hist_count": ("", None)}

    def initiate(self, arrays: Rows, rows: np.ndarray) -> None:
        arrays.ca[rows], arrays.armed[rows], arrays.rho[rows] = 1, 0, 0.0
        arrays.hist_count[rows] = 0
        self._remember(arrays, rows, arrays.x[rows], arrays.p[rows], None, None, arrays.t[rows])

    def _remember(self, arrays: Rows, rows: np.ndarray, x: np.ndarray, p: np.ndarray,
                  z: np.ndarray | None, r: np.ndarray | None, t: np.ndarray) -> None:
        """Shift the per-track history (oldest first) and append this update."""
        for name, v in (("hist_x", x), ("hist_p", p), ("hist_z", z), ("hist_r", r), ("hist_t", t)):
            a = getattr(arrays, name)
            a[rows, :-1] = a[rows, 1:]
            a[rows, -1] = np.nan if v is None else v
        arrays.hist_count[rows] += 1

    def update(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray, convert: Convert) -> Result:
        d = arrays.dim
        x, p = arrays.x[rows].copy(), arrays.p[rows].copy()
        ca = arrays.ca[rows].astype(bool)
        f_cv, q_cv = models.motion("cv", dt, 3, d, self.cv_noise)
        xp, pp = predict(x, p, f_cv, q_cv)
        if ca.any():
            acc = np.linalg.norm(x[ca, 2 * d:], axis=1)
            qa = self.ca_noise * acc / np.maximum(np.abs(dt[ca]), 1e-9)
            f, qm = models.motion("ca", dt[ca], 3, d, qa)
            xp[ca], pp[ca] = predict(x[ca], p[ca], f, qm)
        z, r = convert(xp, pp)
        xn, pn, nis, ok = kalman.update(xp, pp, z, r)
        # manoeuvre detector (CV tracks) and acceleration significance (CA tracks)
        rho = self.alpha * arrays.rho[rows] + np.where(ok, nis, 0.0)
        a = xn[:, 2 * d:]
        paa = pn[:, 2 * d:, 2 * d:] + 1e-12 * np.eye(d)
        sig = einsum("ni,ni->n", a, kalman.solve(paa, a[:, :, None])[:, :, 0])
        rho = np.where(ca, self.alpha * arrays.rho[rows] + np.where(ok, sig, 0.0), rho)
        good = rows[ok]
        self._remember(arrays, good, xn[ok], pn[ok], z[ok], r[ok], arrays.t[good] + dt[ok])
        arrays.rho[good] = rho[ok]
        # CA -> CV: acceleration no longer significant; arms the detector
        settle = ok & ca & (rho < self.settle)
        if settle.any():
            xn[settle, 2 * d:] = 0.0
            pn[settle, 2 * d:, :] = 0.0
            pn[settle, :, 2 * d:] = 0.0
            s_rows = rows[settle]
            arrays.ca[s_rows], arrays.armed[s_rows], arrays.rho[s_rows] = 0, 1, 0.0
        # CV -> CA: manoeuvre detected; re-estimate over the detection window
        onset = ok & ~ca & (arrays.armed[rows] > 0) & (rho > self.detect) & \
            (arrays.hist_count[rows] > self.window + 1)
        if onset.any():
            xr, pr = self._restart(arrays, rows[onset])
            xn[onset], pn[onset] = xr, pr
            o_rows = rows[onset]
            arrays.ca[o_rows], arrays.rho[o_rows] = 1, 0.0
        return xn, pn, nis, ok

    def _restart(self, arrays: Rows, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CA from the CV estimate before the window, re-run over the window's measurements."""
        d = arrays.dim
        x = arrays.hist_x[rows, 0].copy()
        p = arrays.hist_p[rows, 0].copy()
        p[:, 2 * d:, 2 * d:] += self.accel_prior**2 * np.eye(d)
        t = arrays.hist_t[rows, 0]
        for k in range(1, self.window + 1):
            tk = arrays.hist_t[rows, k]
            f, qm = models.motion("ca", tk - t, 3, d, 0.0)
            xp, pp = predict(x, p, f, qm)
            x, p, _, _ = kalman.update(xp, pp, arrays.hist_z[rows, k], arrays.hist_r[rows, k])
            t = tk
        return x, p

    def update_pda(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray, weighted: Any
                   ) -> None:
        """No update by weighted detections of its own: the tracker's equivalent
        measurement serves."""
        return None

    def inflate(self, arrays: Rows, rows: np.ndarray, dp: np.ndarray) -> None:
        """The tracker added dp to the covariances of rows: the history keeps the
        filtered states as they were."""

    def labels(self, arrays: Rows, rows: np.ndarray) -> list[str]:
        return ["ca" if ca else "cv" for ca in arrays.ca[rows].tolist()]
