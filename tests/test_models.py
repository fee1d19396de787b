"""Unit tests of zenoh_track.models against hand-computed CV / CA matrices.

Bar-Shalom, Li & Kirubarajan (2001) sec. 6.2.2-6.2.3 (continuous white noise, here of
spectral density q^2 |dt| over a step dt), per axis:
  CV (order 2): F = [[1, dt], [0, 1]],  Q = q^2 |dt| [[dt^3/3, dt^2/2], [dt^2/2, dt]]
  CA (order 3): F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]],
                Q = q^2 |dt| [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2],
                              [dt^3/6, dt^2/2, dt]].
The full matrices use the state layout of PROTOCOL.md (all positions, then all
velocities, then all accelerations), i.e. kron(per-axis matrix, I_dim).

All numbers below are worked out by hand for dt = 2 and q = 3 (q^2 = 9):
  CV: F_axis = [[1, 2], [0, 1]]; Q_axis / 9 = 2 [[8/3, 2], [2, 2]];
      Q_axis = [[48, 36], [36, 36]].
  CA: F_axis = [[1, 2, 2], [0, 1, 2], [0, 0, 1]];
      Q_axis / 9 = 2 [[32/20, 16/8, 8/6], [16/8, 8/3, 4/2], [8/6, 4/2, 2]];
      Q_axis = [[28.8, 36, 24], [36, 48, 36], [24, 36, 36]].
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zenoh_track.estimation import models, turn
from zenoh_track.estimation.imm import ModeSet

DT = np.array([2.0])
Q_STD = 3.0

# --- CV, 2-D: state [x, y, vx, vy]
F_CV2 = np.array([
    [1, 0, 2, 0],
    [0, 1, 0, 2],
    [0, 0, 1, 0],
    [0, 0, 0, 1],
], dtype=float)
Q_CV2 = np.kron(np.array([[48.0, 36.0], [36.0, 36.0]]), np.eye(2))

# --- CV, 3-D: state [x, y, z, vx, vy, vz]
F_CV3 = np.array([
    [1, 0, 0, 2, 0, 0],
    [0, 1, 0, 0, 2, 0],
    [0, 0, 1, 0, 0, 2],
    [0, 0, 0, 1, 0, 0],
    [0, 0, 0, 0, 1, 0],
    [0, 0, 0, 0, 0, 1],
], dtype=float)
Q_CV3 = np.kron(np.array([[48.0, 36.0], [36.0, 36.0]]), np.eye(3))

# --- CA, 2-D: state [x, y, vx, vy, ax, ay]
F_CA2 = np.array([
    [1, 0, 2, 0, 2, 0],
    [0, 1, 0, 2, 0, 2],
    [0, 0, 1, 0, 2, 0],
    [0, 0, 0, 1, 0, 2],
    [0, 0, 0, 0, 1, 0],
    [0, 0, 0, 0, 0, 1],
], dtype=float)
Q_CA2 = np.kron(np.array([[28.8, 36.0, 24.0], [36.0, 48.0, 36.0], [24.0, 36.0, 36.0]]), np.eye(2))

# --- CA, 3-D: state [x, y, z, vx, vy, vz, ax, ay, az]
F_CA3 = np.array([
    [1, 0, 0, 2, 0, 0, 2, 0, 0],
    [0, 1, 0, 0, 2, 0, 0, 2, 0],
    [0, 0, 1, 0, 0, 2, 0, 0, 2],
    [0, 0, 0, 1, 0, 0, 2, 0, 0],
    [0, 0, 0, 0, 1, 0, 0, 2, 0],
    [0, 0, 0, 0, 0, 1, 0, 0, 2],
    [0, 0, 0, 0, 0, 0, 1, 0, 0],
    [0, 0, 0, 0, 0, 0, 0, 1, 0],
    [0, 0, 0, 0, 0, 0, 0, 0, 1],
], dtype=float)
Q_CA3 = np.kron(np.array([[28.8, 36.0, 24.0], [36.0, 48.0, 36.0], [24.0, 36.0, 36.0]]), np.eye(3))

CASES = [
    pytest.param(2, 2, F_CV2, Q_CV2, id="cv-2d"),
    pytest.param(2, 3, F_CV3, Q_CV3, id="cv-3d"),
    pytest.param(3, 2, F_CA2, Q_CA2, id="ca-2d"),
    pytest.param(3, 3, F_CA3, Q_CA3, id="ca-3d"),
]


@pytest.mark.parametrize(("order", "dim", "f_ref", "q_ref"), CASES)
def test_transition_matches_hand_computed(order, dim, f_ref, q_ref):
    f = models.transition(DT, order, dim)
    assert f.shape == (1, order * dim, order * dim)
    np.testing.assert_allclose(f[0], f_ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("order", "dim", "f_ref", "q_ref"), CASES)
def test_process_noise_matches_hand_computed(order, dim, f_ref, q_ref):
    q = models.process_noise(DT, order, dim, Q_STD)
    assert q.shape == (1, order * dim, order * dim)
    np.testing.assert_allclose(q[0], q_ref, rtol=1e-12, atol=1e-12)


def test_noise_terms_per_axis():
    # dt = 2, density |dt| = 2: CV 2 [[8/3, 2], [2, 2]]; CA's first row 2 [32/20, 16/8, 8/6]
    np.testing.assert_allclose(models.noise_terms(DT, 2)[..., 0], [[16 / 3, 4], [4, 4]],
                               rtol=1e-15)
    np.testing.assert_allclose(models.noise_terms(DT, 3)[0, :, 0], [3.2, 4.0, 8 / 3],
                               rtol=1e-15)


def test_batch_rows_use_their_own_dt():
    # q = 1. Row 0: dt = 1 -> F_axis [[1, 1], [0, 1]], Q_axis [[1/3, 1/2], [1/2, 1]]
    # Row 1: dt = 2 -> F_axis [[1, 2], [0, 1]], Q_axis 2 [[8/3, 2], [2, 2]]
    # Row 2: dt = 0 -> identity F, zero Q
    dt = np.array([1.0, 2.0, 0.0])
    f = models.transition(dt, 2, 1)
    q = models.process_noise(dt, 2, 1, 1.0)
    np.testing.assert_allclose(f[0], [[1, 1], [0, 1]])
    np.testing.assert_allclose(f[1], [[1, 2], [0, 1]])
    np.testing.assert_allclose(f[2], np.eye(2))
    np.testing.assert_allclose(q[0], [[1 / 3, 0.5], [0.5, 1.0]])
    np.testing.assert_allclose(q[1], [[16 / 3, 4], [4, 4]])
    np.testing.assert_allclose(q[2], np.zeros((2, 2)))


def test_process_noise_per_row_q():
    # q may be given per row: q = [1, 3] at dt = 2 gives Q_axis = q^2 [[16/3, 4], [4, 4]]
    q = models.process_noise(np.array([2.0, 2.0]), 2, 1, np.array([1.0, 3.0]))
    np.testing.assert_allclose(q[0], [[16 / 3, 4], [4, 4]])
    np.testing.assert_allclose(q[1], [[48, 36], [36, 36]])


def test_predict_forward_cv_2d():
    # x = [10, 20, 1, 2], P = I, dt = 2, q = 1.
    # F x = [10 + 2*1, 20 + 2*2, 1, 2] = [12, 24, 1, 2].
    # F F' for one axis [[1, 2], [0, 1]] [[1, 0], [2, 1]] = [[5, 2], [2, 1]];
    # + Q_axis [[16/3, 4], [4, 4]] = [[31/3, 6], [6, 5]].
    x = np.array([[10.0, 20.0, 1.0, 2.0]])
    p = np.eye(4)[None]
    xp, pp = models.predict(x, p, np.array([2.0]), 2, 2, 1.0)
    np.testing.assert_allclose(xp[0], [12, 24, 1, 2])
    a, b = 31 / 3, 6
    np.testing.assert_allclose(pp[0], [[a, 0, b, 0], [0, a, 0, b], [b, 0, 5, 0], [0, b, 0, 5]])


def test_predict_negative_dt_uses_abs_dt_for_noise():
    # Same as above but dt = -2 (extrapolation backwards):
    # F x = [10 - 2, 20 - 4, 1, 2] = [8, 16, 1, 2].
    # F F' per axis = [[1, -2], [0, 1]] [[1, 0], [-2, 1]] = [[5, -2], [-2, 1]].
    # Noise with |dt| = 2: Q_axis = [[16/3, 4], [4, 4]] -> P = [[31/3, 2], [2, 5]].
    # (A signed dt would give Q_axis = [[16/3, -4], [-4, 4]] -> [[31/3, -6], [-6, 5]].)
    x = np.array([[10.0, 20.0, 1.0, 2.0]])
    p = np.eye(4)[None]
    xp, pp = models.predict(x, p, np.array([-2.0]), 2, 2, 1.0)
    np.testing.assert_allclose(xp[0], [8, 16, 1, 2])
    np.testing.assert_allclose(pp[0], [[31 / 3, 0, 2, 0], [0, 31 / 3, 0, 2], [2, 0, 5, 0],
                                       [0, 2, 0, 5]], atol=1e-12)
    np.testing.assert_allclose(models.process_noise(np.array([-2.0]), 2, 2, 1.0),
                               models.process_noise(np.array([2.0]), 2, 2, 1.0))


def test_process_noise_negative_dt_ca():
    # CA at dt = -2 must equal CA at dt = +2 (Q_CA3 with q = 3); a signed dt would flip
    # the sign of the odd powers of dt.
    q = models.process_noise(np.array([-2.0]), 3, 3, Q_STD)
    np.testing.assert_allclose(q[0], Q_CA3, rtol=1e-12, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(q[0]) > -1e-9)


def test_predict_ca_3d_state():
    # CA 3-D, dt = 2: per axis p' = p + 2 v + 2 a, v' = v + 2 a, a' = a.
    # x: p = [1, 2, 3], v = [4, 5, 6], a = [7, 8, 9]
    # p' = [1 + 8 + 14, 2 + 10 + 16, 3 + 12 + 18] = [23, 28, 33]
    # v' = [4 + 14, 5 + 16, 6 + 18] = [18, 21, 24]
    x = np.arange(1.0, 10.0)[None]
    p = np.zeros((1, 9, 9))
    xp, pp = models.predict(x, p, DT, 3, 3, Q_STD)
    np.testing.assert_allclose(xp[0], [23, 28, 33, 18, 21, 24, 7, 8, 9])
    # with P = 0 the predicted covariance is exactly Q
    np.testing.assert_allclose(pp[0], Q_CA3, rtol=1e-12, atol=1e-12)


def test_predict_is_symmetric_and_matches_f_p_ft_plus_q():
    rng = np.random.default_rng(7)
    n = 6
    a = rng.standard_normal((5, n, n))
    p = a @ a.transpose(0, 2, 1)
    x = rng.standard_normal((5, n))
    dt = np.array([0.5, -1.0, 2.0, 0.0, 3.3])
    xp, pp = models.predict(x, p, dt, 2, 3, 0.7)
    f = models.transition(dt, 2, 3)
    q = models.process_noise(dt, 2, 3, 0.7)
    np.testing.assert_allclose(xp, np.einsum("nij,nj->ni", f, x), rtol=1e-12)
    np.testing.assert_allclose(pp, f @ p @ f.transpose(0, 2, 1) + q, rtol=1e-12, atol=1e-12)
    assert np.array_equal(pp, pp.transpose(0, 2, 1))


@pytest.mark.parametrize("order,dim", [(2, 2), (2, 3), (3, 2), (3, 3)])
@pytest.mark.parametrize("per_row_q", [False, True])
def test_predict_position_is_the_position_part_of_the_textbook_prediction(order, dim,
                                                                         per_row_q):
    """The gate's shortcut equals the position rows of F P F' + Q (reference form)."""
    from reference import estimation as reference

    rng = np.random.default_rng(order * 10 + dim)
    n_rows, n = 40, order * dim
    x = rng.normal(size=(n_rows, n)) * 100
    a = rng.normal(size=(n_rows, n, n))
    p = a @ a.transpose(0, 2, 1) + np.eye(n)
    dt = rng.uniform(-2.0, 3.0, n_rows)
    q = rng.uniform(0.1, 3.0, n_rows) if per_row_q else 1.5
    f, qm = reference.motion_matrices(dt, order, dim, q)
    xp, pp = reference.predict(x, p, f, qm)
    mean, rows = models.predict_position(x, p, dt, order, dim, q)
    assert np.allclose(mean, xp[:, :dim], rtol=1e-12, atol=1e-9)
    assert np.allclose(rows, pp[:, :dim, :], rtol=1e-10, atol=1e-9 * np.abs(pp).max())


# --- the 3-D coordinated turn with the rate from v and a ("turn", Watson & Blair 1992)
def _turn_truth(t: float, w: float = 0.196, v: float = 200.0) -> np.ndarray:
    """A level turn at w rad/s from the origin heading East: [p, v, a] (9,)."""
    s, c = np.sin(w * t), np.cos(w * t)
    return np.array([v / w * s, v / w * (1 - c), 0.0, v * c, v * s, 0.0,
                     -v * w * s, v * w * c, 0.0])


def test_turn_predicts_a_steady_turn_exactly():
    x = _turn_truth(0.0)[None]
    assert turn.turn_rate(x, 3, 0.5)[0] == pytest.approx(0.196)
    for dt in (1.0, 4.0, -2.0):
        f, _, _ = turn.turn_model(x, np.array([dt]), 3, 1.0, 0.5)
        np.testing.assert_allclose(f[0] @ x[0], _turn_truth(dt), atol=1e-9)


@pytest.mark.parametrize("w, dt", [(0.3, 4.0), (0.02, 1.0), (0.5, -3.0), (0.001, 2.0), (0.0, 2.0)])
def test_turn_axis_matches_the_matrix_exponential_and_van_loan(w, dt):
    from scipy.linalg import expm

    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -w * w, 0.0]])
    m = np.zeros((6, 6))  # Van Loan (1978): Q of the white jerk over |dt|
    m[:3, :3], m[:3, 3:], m[3:, 3:] = -a, np.diag([0.0, 0.0, 1.0]), a.T
    e = expm(m * abs(dt))
    q_ref = e[3:, 3:].T @ e[:3, 3:] * abs(dt) * Q_STD**2  # density q^2 |dt|
    phi, q = turn.turn_axis(np.array([dt]), np.array([w]), Q_STD)
    np.testing.assert_allclose(phi[0], expm(a * dt), atol=1e-12)
    np.testing.assert_allclose(q[0], q_ref, rtol=1e-6, atol=1e-12)  # series below TURN_SMALL


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("dt", [1.0, -2.0, 4.0])
def test_turn_jacobian_matches_finite_differences(dim, dt):
    rng = np.random.default_rng(dim)
    x = rng.normal(0, 1, (1, 3 * dim)) * np.r_[[1000.0] * dim, [200.0] * dim, [20.0] * dim]

    def step(y: np.ndarray) -> np.ndarray:
        return turn.turn_model(y[None], np.array([dt]), dim, 1.0, 0.5)[0][0] @ y

    num = np.empty((3 * dim, 3 * dim))
    for i in range(3 * dim):
        h = np.zeros(3 * dim)
        h[i] = 1e-5 * max(1.0, abs(x[0, i]))
        num[:, i] = (step(x[0] + h) - step(x[0] - h)) / (2 * h[i])
    _, _, jac = turn.turn_model(x, np.array([dt]), dim, 1.0, 0.5)
    np.testing.assert_allclose(jac[0], num, atol=1e-6 * np.abs(num).max())


def test_turn_rate_is_capped_and_zero_when_slow_or_straight():
    x = np.zeros((3, 9))
    x[0, 3], x[0, 7] = 100.0, 200.0  # 2 rad/s asked: capped
    x[1, 3], x[1, 7] = 0.5, 10.0  # slower than 1 m/s
    x[2, 3], x[2, 6] = 200.0, 30.0  # acceleration along v: no turn
    np.testing.assert_allclose(turn.turn_rate(x, 3, 0.5), [0.5, 0.0, 0.0])
    assert not turn.turn_rate_gradient(x, 3, 0.5).any()


@pytest.mark.parametrize("kind", ["turn", "ca"])
def test_an_imm_mode_of_the_turn_holds_a_steady_4g_turn(kind):
    """One "turn" mode (the EKF of `turn.turn_model`) against
    one CA mode with the same jerk noise, on 1 Hz positions (sigma 30 m) of a 4 g turn:
    the turn model's error stays near the noise, the CA's lags; without the Jacobian
    of the rate the turn filter diverged (400 m and more at this noise)."""
    from zenoh_track import defaults
    from zenoh_track.estimation import imm_jit
    from zenoh_track.estimation.catalog import Filter
    from zenoh_track.estimation.imm import IMM
    from zenoh_track.estimation.ucm import CMKFConversion
    from zenoh_track.tracking.batches import Labelled
    from zenoh_track.tracking.tracker import Tracker
    from zenoh_track.wire import Measurement

    imm = IMM(((kind, kind, 0.5, 0.0),), 1e9)
    assert imm_jit.applies(imm)  # compiled once warm (tests/test_imm_jit.py)
    tracker = Tracker.from_config(filter=Filter(imm, defaults.Q_CV, CMKFConversion, "imm"))
    rng = np.random.default_rng(3)
    errors = []
    for t in range(90):
        pos = _turn_truth(float(t))[:3] + rng.normal(0.0, 30.0, 3)
        tracker.step(Labelled.of([Measurement("s", "a", float(t), 3, False, tuple(pos),
                                              (30.0,) * 3, (0.0, 0.0, 0.0), None)]))
        if t >= 30:
            snap = tracker.snapshot(float(t))
            errors.append(np.sum((snap.pos[0] - _turn_truth(float(t))[:3]) ** 2))
    rmse = float(np.sqrt(np.mean(errors)))
    assert rmse < 30.0 if kind == "turn" else rmse > 40.0


def test_a_cv_modes_velocity_change_over_a_step_is_bounded():
    """The default IMM's widest mode (55 m/s^2) is itself up to 5 s; beyond, the velocity
    variance it adds over a step stays at dv_cap^2 (q |dt| <= dv_cap, per axis), and
    its position variance grows as dt^2, not dt^4 (docs/accuracy.md, "Beyond 5 s")."""
    imm = ModeSet().imm()
    j = [m[0] for m in imm.modes].index("cv55")
    assert imm.dv_cap == 275.0
    unbounded = dataclasses.replace(imm, dv_cap=0.0)
    x0, p0 = np.zeros((4, 9)), np.zeros((4, 9, 9))
    dt = np.array([1.0, 5.0, 10.0, 20.0])
    _, p = imm.predict_mode(j, dt, x0, p0, 3)
    _, pu = unbounded.predict_mode(j, dt, x0, p0, 3)
    np.testing.assert_allclose(p[:2], pu[:2], rtol=1e-15)  # up to 5 s: as designed
    np.testing.assert_allclose(p[:, 3, 3], [55.0**2, 275.0**2, 275.0**2, 275.0**2])
    np.testing.assert_allclose(p[:, 0, 0], (np.minimum(55.0, 275.0 / dt) * dt**2) ** 2 / 3)
    assert (p[2:, 0, 0] < pu[2:, 0, 0] / 3).all()
    assert (imm.predict_mode(0, dt, x0, p0, 3)[1] == unbounded.predict_mode(  # the quiet
        0, dt, x0, p0, 3)[1]).all()  # mode: far from its bound
