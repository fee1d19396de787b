"""clients/evaluation/metrics.py: PCRB, polar Jacobian, chi2 intervals, NEES, RMSE windows,
scenario B."""

from __future__ import annotations

import math

import numpy as np
import pytest

from zenoh_track.clients.evaluation.metrics import (
    chi2_cdf,
    chi2_interval,
    chi2_ppf_wh,
    cv_model,
    j0_diffuse,
    j1_two_point,
    linear_info,
    nees,
    pcrb,
    pcrb_polar,
    polar_info,
    polar_jacobian,
    position_bound,
    rmse_windows,
    scenario_b_bound,
    velocity_bound,
)


def _polar(s: np.ndarray, elevation: bool) -> np.ndarray:
    x, y = s[0], s[1]
    if not elevation:
        return np.array([math.hypot(x, y), math.atan2(x, y)])
    z = s[2]
    return np.array([math.sqrt(x * x + y * y + z * z), math.atan2(x, y),
                     math.atan2(z, math.hypot(x, y))])


def _kf_covariances(F, Q, H, R, P0, K):
    """Test-local KF covariance recursion (Joseph form)."""
    out, P = [P0], P0
    n = P0.shape[0]
    for _ in range(1, K):
        P = F @ P @ F.T + Q
        S = H @ P @ H.T + R
        G = P @ H.T @ np.linalg.inv(S)
        A = np.eye(n) - G @ H
        P = A @ P @ A.T + G @ R @ G.T
        out.append(P)
    return np.array(out)


@pytest.mark.parametrize("d", [2, 3])
def test_pcrb_linear_equals_kf(d: int) -> None:
    rng = np.random.default_rng(1)
    n, K = 2 * d, 60
    F, Q = cv_model(d, 1.0, 2.0)
    H = np.hstack([np.eye(d), np.zeros((d, d))])
    R = np.diag(rng.uniform(20.0, 200.0, d) ** 2)
    A = rng.standard_normal((n, n))
    P0 = A @ A.T * 100.0 + np.eye(n)
    truths = rng.standard_normal((5, K, n))  # irrelevant for a linear measurement
    bound = pcrb(truths, F, Q, np.linalg.inv(P0), linear_info(H, R))
    kf = _kf_covariances(F, Q, H, R, P0, K)
    np.testing.assert_allclose(bound, kf, rtol=1e-8, atol=1e-8)


def test_pcrb_single_run_equals_true_state_ekf() -> None:
    # one truth: the PCRB is the EKF covariance with Jacobians taken at the true state
    rng = np.random.default_rng(2)
    F, Q = cv_model(3, 1.0, 1.0)
    x = np.array([10_000.0, 10_000.0, 10_000.0, -300.0, -300.0, 0.0])
    truths = [x]
    for _ in range(49):
        a = rng.standard_normal(3)
        x = F @ x + np.concatenate([0.5 * a, a])
        truths.append(x)
    truths = np.array(truths)[None]
    sr, sa = 50.0, math.radians(0.5)
    J0 = j0_diffuse(truths[:, 0], sr, sa, sa, sigma_v=500.0)
    bound = pcrb_polar(truths, F, Q, J0, sr, sa, sa)
    R = np.diag([sr**2, sa**2, sa**2])
    P = np.linalg.inv(J0)
    for k in range(1, truths.shape[1]):
        P = F @ P @ F.T + Q
        H = polar_jacobian(truths[0, k])
        G = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        P = (np.eye(6) - G @ H) @ P @ (np.eye(6) - G @ H).T + G @ R @ G.T
        np.testing.assert_allclose(bound[k], P, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("elevation", [True, False])
def test_polar_jacobian_finite_differences(elevation: bool) -> None:
    rng = np.random.default_rng(3)
    d = 3 if elevation else 2
    states = np.hstack([rng.uniform(-20_000, 20_000, (20, d)), rng.uniform(-300, 300, (20, d))])
    states[0, :d] = 300.0  # close in, nearly overhead for 3-D
    H = polar_jacobian(states, elevation=elevation)
    assert H.shape == (20, d, 2 * d)
    for s, Hs in zip(states, H, strict=True):
        num = np.zeros_like(Hs)
        for j in range(2 * d):
            h = 1e-3 * max(1.0, abs(s[j]))
            e = np.zeros(2 * d)
            e[j] = h
            num[:, j] = (_polar(s + e, elevation) - _polar(s - e, elevation)) / (2 * h)
        np.testing.assert_allclose(Hs, num, rtol=1e-5, atol=1e-12)


def test_polar_info_is_mean_over_runs() -> None:
    rng = np.random.default_rng(4)
    states = np.hstack([rng.uniform(1_000, 9_000, (7, 3)), np.zeros((7, 3))])
    sr, sa = 50.0, 0.01
    R = np.diag([sr**2, sa**2, sa**2])
    expected = np.mean([polar_jacobian(s).T @ np.linalg.inv(R) @ polar_jacobian(s)
                        for s in states], axis=0)
    np.testing.assert_allclose(polar_info(sr, sa, sa)(states), expected, rtol=1e-10)


def test_pcrb_polar_2d_runs_and_two_point_matches_diffuse() -> None:
    F, Q = cv_model(2, 1.0, 1.0)
    K = 30
    x0 = np.array([5_000.0, 8_000.0, -100.0, 50.0])
    truths = np.array([np.linalg.matrix_power(F, k) @ x0 for k in range(K)])[None]
    sr, sa = 30.0, math.radians(0.3)
    b1 = pcrb_polar(truths, F, Q, j0_diffuse(truths[:, 0], sr, sa, None, 1e5), sr, sa, None)
    J1 = j1_two_point(truths[:, 0], truths[:, 1], F, sr, sa, None)
    b2 = pcrb_polar(truths[:, 1:], F, Q, J1, sr, sa, None)
    assert b1.shape == (K, 4, 4) and b2.shape == (K - 1, 4, 4)
    # the two initiations differ only by the first step's process noise and the diffuse prior
    np.testing.assert_allclose(position_bound(b2, 2), position_bound(b1[1:], 2), rtol=1e-3)
    np.testing.assert_allclose(velocity_bound(b2, 2), velocity_bound(b1[1:], 2), rtol=1e-3)


@pytest.mark.parametrize("dof, runs, lo, hi", [(6, 100, 5.34, 6.70), (9, 100, 8.19, 9.85),
                                               (4, 100, 3.46, 4.57)])
def test_chi2_interval(dof: int, runs: int, lo: float, hi: float) -> None:
    a, b = chi2_interval(dof, runs)
    assert abs(a - lo) < 0.02 and abs(b - hi) < 0.02
    # the Wilson-Hilferty approximation agrees closely at these degrees of freedom
    assert abs(chi2_ppf_wh(0.025, dof * runs) / runs - a) < 0.01
    assert abs(chi2_ppf_wh(0.975, dof * runs) / runs - b) < 0.01


def test_chi2_small_dof_exact() -> None:
    # closed forms: chi2(2) cdf = 1 - exp(-x/2); chi2(1) 95 % quantile = 1.959964^2
    for x in (0.1, 1.0, 5.0, 20.0):
        assert abs(chi2_cdf(x, 2) - (1 - math.exp(-x / 2))) < 1e-12
    assert abs(chi2_interval(1, 1, 0.90)[1] - 1.959964**2) < 1e-5
    lo, hi = chi2_interval(2, 1)
    assert abs(lo - (-2 * math.log(0.975))) < 1e-9 and abs(hi - (-2 * math.log(0.025))) < 1e-9


def test_nees_of_consistent_errors_averages_to_n() -> None:
    rng = np.random.default_rng(5)
    n, m = 6, 20_000
    A = rng.standard_normal((m, n, n))
    P = A @ A.transpose(0, 2, 1) + 0.1 * np.eye(n)
    err = np.einsum("mij,mj->mi", np.linalg.cholesky(P), rng.standard_normal((m, n)))
    e = nees(err, P)
    assert e.shape == (m,)
    tol = 4 * math.sqrt(2 * n / m)  # 4 standard deviations of the sample mean
    assert abs(e.mean() - n) < tol
    # scalar case
    assert nees(np.array([3.0, 4.0]), np.eye(2) * 25.0) == pytest.approx(1.0)


def test_rmse_windows() -> None:
    sq = np.array([[1.0, 4.0, 9.0, 16.0], [1.0, 4.0, 9.0, np.nan]])
    assert rmse_windows(sq, [0, 2, 4]) == pytest.approx([math.sqrt(2.5), math.sqrt(34 / 3)])
    assert rmse_windows(sq, [(1, 3)]) == pytest.approx([math.sqrt(6.5)])


def test_scenario_b_bound() -> None:
    pos, vel = scenario_b_bound(runs=100, seed=0)
    assert pos.shape == vel.shape == (200,)
    mean_sqrt = pos[20:].mean()
    assert 95.0 < mean_sqrt < 120.0
    # position bound collapses during the overhead pass near t = 33 s
    assert pos[30:36].min() < 0.5 * pos[20]
    assert np.all(np.isfinite(pos)) and np.all(vel[1:] < vel[0])
