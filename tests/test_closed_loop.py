"""The steady state of every filter the service offers is stable: the closed-loop matrix
(I - K H) F of the Kalman filter at its steady-state gain K has every eigenvalue inside
the unit circle with a margin, for measurement variances from 0 (positions stated exact)
to large, at the 1 s and 2 s scan intervals of the scenarios.

The steady state comes from iterating the Riccati recursion (textbook form, here) on the
service's own F and Q (`models.motion`) of every model of every filter: each of the
default IMM's modes, CV, CA, the EKF's CV, the VDF's two models and the optional turn
modes. With the piecewise-constant white-noise model the service used before
(Bar-Shalom, Li & Kirubarajan 2001, sec. 6.3.2) a zero measurement variance gives gains
alpha = 1, beta = 2 and an eigenvalue at -1; with the continuous model (sec. 6.2.2)
beta = 3 - sqrt(3) and the eigenvalues 0.27 (CV).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from zenoh_track.estimation import models
from zenoh_track.estimation.catalog import FILTERS, FilterSpec
from zenoh_track.estimation.filters import SingleModelFilter
from zenoh_track.estimation.imm import IMM
from zenoh_track.estimation.vdf import VDF

VARIANCES = (0.0, 1e-4, 1e-2, 1.0, 1e2, 1e4)  # m^2 per axis
PERIODS = (1.0, 2.0)  # s


def filter_models(name: str) -> list[tuple[str, str, float, float, int]]:
    """(label, kind, q, omega, order) of every motion model of filter `name` as the
    service builds it without options (turn modes added, as `--imm-turn` would)."""
    spec = FilterSpec(name, imm_turn=1.8) if name == "imm" else FilterSpec(name)
    updater = spec.build().updater
    if isinstance(updater, IMM):
        return [(m[0], m[1], m[2], m[3], 3) for m in updater.modes]
    if isinstance(updater, VDF):
        # the CA model's noise for an acceleration of 1 and 20 m/s^2 over a 1 s step
        return [("cv", "cv", updater.cv_noise, 0.0, 3),
                ("ca 1", "ca", updater.ca_noise * 1.0, 0.0, 3),
                ("ca 20", "ca", updater.ca_noise * 20.0, 0.0, 3)]
    assert isinstance(updater, SingleModelFilter)
    return [(updater.kind, updater.kind, updater.q, 0.0, updater.order)]


def closed_loop(kind: str, order: int, q: float, omega: float, r: float, period: float,
                dim: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The steady-state gain K and the eigenvalues of (I - K H) F (Riccati recursion
    P- = F P F' + Q, K = P- H' (H P- H' + R)^-1, P = (I - K H) P-, iterated to a fixed
    point from a wide prior)."""
    f, qm = models.motion(kind, np.array([period]), order, dim, q, omega)
    f, qm = f[0], qm[0]
    n = len(f)
    h = np.zeros((dim, n))
    h[:, :dim] = np.eye(dim)
    p = np.eye(n) * 1e6
    k = np.zeros((n, dim))
    for _ in range(20000):
        pp = f @ p @ f.T + qm
        s = h @ pp @ h.T + r * np.eye(dim) + 1e-12 * np.eye(dim)
        k_new = np.linalg.solve(s, h @ pp).T
        p = (np.eye(n) - k_new @ h) @ pp
        p = 0.5 * (p + p.T)
        if np.allclose(k_new, k, rtol=1e-11, atol=1e-13):
            break
        k = k_new
    return k_new, np.linalg.eigvals((np.eye(n) - k_new @ h) @ f)


CASES = [pytest.param(name, label, kind, q, w, order, id=f"{name}-{label}")
         for name in FILTERS for label, kind, q, w, order in filter_models(name)]


@pytest.mark.parametrize(("name", "label", "kind", "q", "omega", "order"), CASES)
def test_closed_loop_inside_unit_circle(name, label, kind, q, omega, order):
    for period in PERIODS:
        for r in VARIANCES:
            _, eig = closed_loop(kind, order, q, omega, r, period)
            radius = np.abs(eig).max()
            # a margin: memory grows as R grows against Q, but stays finite
            assert radius < 1 - 1e-3, (name, label, period, r, eig)
            # no oscillation at half the measurement rate (an eigenvalue near -1)
            assert eig.real.min() > -0.5, (name, label, period, r, eig)
        _, eig = closed_loop(kind, order, q, omega, 0.0, period)
        assert np.abs(eig).max() < 0.5, (name, label, period, eig)  # exact positions


def test_exact_positions_cv_gains_are_the_continuous_models():
    # Bar-Shalom et al. 2001 sec. 6.2.2 at R = 0: alpha = 1, beta = 3 - sqrt(3), and the
    # closed loop's eigenvalues 2 - sqrt(3) = 0.268 and 0
    k, eig = closed_loop("cv", 2, 1.0, 0.0, 0.0, 1.0, dim=1)
    np.testing.assert_allclose(k[:, 0], [1.0, 3 - math.sqrt(3)], rtol=1e-6)
    np.testing.assert_allclose(sorted(np.abs(eig)), [0.0, 2 - math.sqrt(3)], atol=1e-6)
