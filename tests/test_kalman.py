"""Unit tests of zenoh_track.kalman.update against hand-worked Kalman updates.

H = [I_d 0], S = H P H' + R (+ S_FLOOR I, 1e-9 m^2, negligible at rtol 1e-8 below),
K = P H' S^-1, x+ = x + K (z - H x), P+ = (I - K H) P (I - K H)' + K R K'
(for the optimal gain this equals P - K S K'), NIS = nu' S^-1 nu.
"""

from __future__ import annotations

import numpy as np

from zenoh_track.estimation import kalman

RTOL = 1e-8


def test_one_axis_cv_hand_worked():
    # State [p, v], x = [0, 1], P = [[4, 2], [2, 3]], z = 3, R = 2.
    # nu = 3 - 0 = 3; S = 4 + 2 = 6; K = [4, 2] / 6 = [2/3, 1/3].
    # x+ = [0 + 2/3*3, 1 + 1/3*3] = [2, 2].
    # P+ = P - K S K' = [[4 - 16/6, 2 - 8/6], [2 - 8/6, 3 - 4/6]] = [[4/3, 2/3], [2/3, 7/3]].
    # NIS = 3^2 / 6 = 1.5.
    x = np.array([[0.0, 1.0]])
    p = np.array([[[4.0, 2.0], [2.0, 3.0]]])
    z = np.array([[3.0]])
    r = np.array([[[2.0]]])
    xn, pn, nis, ok = kalman.update(x, p, z, r)
    np.testing.assert_allclose(xn[0], [2.0, 2.0], rtol=RTOL)
    np.testing.assert_allclose(pn[0], [[4 / 3, 2 / 3], [2 / 3, 7 / 3]], rtol=RTOL)
    np.testing.assert_allclose(nis, [1.5], rtol=RTOL)
    assert ok.tolist() == [True]


def test_two_axis_cv_hand_worked():
    # 2-D CV, state [x, y, vx, vy]; the axes are uncorrelated, so each is a 1-D update.
    # x axis: Pxx = 4, Pxv = 2, Pvv = 3, R = 4 -> S = 8, K = [1/2, 1/4];
    #   nu = 4 - 0 = 4 -> x = 2, vx = 1 + 1 = 2;
    #   P+ = [[4 - 2, 2 - 1], [2 - 1, 3 - 1/2]] = [[2, 1], [1, 2.5]].
    # y axis: Pyy = 9, Pyv = 3, Pvv = 5, R = 3 -> S = 12, K = [3/4, 1/4];
    #   nu = -6 - 0 = -6 -> y = -4.5, vy = -1 - 1.5 = -2.5;
    #   P+ = [[9 - 6.75, 3 - 2.25], [3 - 2.25, 5 - 0.75]] = [[2.25, 0.75], [0.75, 4.25]].
    # NIS = 4^2/8 + 6^2/12 = 2 + 3 = 5.
    x = np.array([[0.0, 0.0, 1.0, -1.0]])
    p = np.array([[[4, 0, 2, 0], [0, 9, 0, 3], [2, 0, 3, 0], [0, 3, 0, 5]]], dtype=float)
    z = np.array([[4.0, -6.0]])
    r = np.array([np.diag([4.0, 3.0])])
    xn, pn, nis, ok = kalman.update(x, p, z, r)
    np.testing.assert_allclose(xn[0], [2.0, -4.5, 2.0, -2.5], rtol=RTOL)
    expected_p = [[2, 0, 1, 0], [0, 2.25, 0, 0.75], [1, 0, 2.5, 0], [0, 0.75, 0, 4.25]]
    np.testing.assert_allclose(pn[0], expected_p, rtol=RTOL, atol=1e-8)
    np.testing.assert_allclose(nis, [5.0], rtol=RTOL)
    assert ok.tolist() == [True]


def test_correlated_position_only_hand_worked():
    # n = d = 2 (position-only state), P = [[2, 1], [1, 2]], R = I, x = 0, z = [8, 0].
    # S = [[3, 1], [1, 3]], det 8, S^-1 = [[3, -1], [-1, 3]] / 8.
    # K = P S^-1 = [[2*3 - 1, -2 + 3], [3 - 2, -1 + 6]] / 8 = [[5, 1], [1, 5]] / 8.
    # x+ = K [8, 0] = [5, 1].
    # P+ = (I - K) P = [[3, -1], [-1, 3]] / 8 @ [[2, 1], [1, 2]] = [[5, 1], [1, 5]] / 8.
    # NIS = [8, 0] S^-1 [8, 0]' = 64 * 3 / 8 = 24.
    x = np.zeros((1, 2))
    p = np.array([[[2.0, 1.0], [1.0, 2.0]]])
    z = np.array([[8.0, 0.0]])
    r = np.eye(2)[None]
    xn, pn, nis, ok = kalman.update(x, p, z, r)
    np.testing.assert_allclose(xn[0], [5.0, 1.0], rtol=RTOL)
    np.testing.assert_allclose(pn[0], np.array([[5.0, 1.0], [1.0, 5.0]]) / 8, rtol=RTOL)
    np.testing.assert_allclose(nis, [24.0], rtol=RTOL)


def test_rows_are_independent():
    # A batch gives the same result for each row as updating that row alone.
    rng = np.random.default_rng(3)
    n_rows, n, d = 7, 6, 3
    a = rng.standard_normal((n_rows, n, n))
    p = a @ a.transpose(0, 2, 1) + np.eye(n)
    b = rng.standard_normal((n_rows, d, d))
    r = b @ b.transpose(0, 2, 1) + 0.1 * np.eye(d)
    x = rng.standard_normal((n_rows, n))
    z = rng.standard_normal((n_rows, d))
    batch = kalman.update(x, p, z, r)
    for i in range(n_rows):
        single = kalman.update(x[i:i + 1], p[i:i + 1], z[i:i + 1], r[i:i + 1])
        for got, want in zip(batch, single, strict=True):
            np.testing.assert_allclose(got[i], want[0], rtol=1e-10, atol=1e-12)


def test_joseph_form_symmetric_and_psd_when_ill_conditioned():
    # A diffuse velocity prior (1e6^2) and near-exact measurement (R = 1e-6 m^2) is the
    # case where P - K S K' loses symmetry / positive semi-definiteness numerically.
    rng = np.random.default_rng(11)
    n_rows, d = 50, 3
    n = 2 * d
    p = np.zeros((n_rows, n, n))
    for i in range(n_rows):
        a = rng.standard_normal((n, n)) * np.repeat([1.0, 1e6], d)[:, None]
        p[i] = a @ a.T
    x = rng.standard_normal((n_rows, n)) * 1e3
    z = rng.standard_normal((n_rows, d)) * 1e3
    r = np.broadcast_to(1e-6 * np.eye(d), (n_rows, d, d)).copy()
    xn, pn, nis, ok = kalman.update(x, p, z, r)
    assert ok.all()
    assert np.array_equal(pn, pn.transpose(0, 2, 1))  # exactly symmetric
    eig = np.linalg.eigvalsh(pn)
    scale = np.abs(eig).max(axis=1)
    assert (eig.min(axis=1) >= -1e-9 * scale).all()


def test_exact_measurement_of_exact_position_gives_zero_gain():
    # P = 0 and R = 0: S = S_FLOOR I, P H' = 0 -> K = 0: state unchanged, P stays 0,
    # no division by zero. NIS = |nu|^2 / S_FLOOR = (4^2 + 4^2) / 1e-9 = 3.2e10, finite.
    x = np.array([[1.0, 2.0, 3.0, 4.0]])
    p = np.zeros((1, 4, 4))
    z = np.array([[5.0, 6.0]])
    r = np.zeros((1, 2, 2))
    with np.errstate(all="raise"):
        xn, pn, nis, ok = kalman.update(x, p, z, r)
    assert ok.tolist() == [True]
    np.testing.assert_array_equal(xn, x)
    np.testing.assert_array_equal(pn, 0.0)
    assert np.isfinite(nis).all()
    np.testing.assert_allclose(nis, [32.0 / kalman.S_FLOOR], rtol=1e-12)


def test_exact_measurement_with_uncertain_prior_snaps_to_measurement():
    # R = 0, P = diag(4, 1) for [p, v] with Ppv = 2: S = 4, K = [1, 1/2];
    # x = [0, 0], z = 2 -> x+ = [2, 1]; P+ = P - K S K' = [[0, 0], [0, 1 - 1]] = 0 for
    # this rank-one P (Pvv = Ppv^2 / Ppp). Up to the 1e-9 floor.
    x = np.zeros((1, 2))
    p = np.array([[[4.0, 2.0], [2.0, 1.0]]])
    xn, pn, nis, ok = kalman.update(x, p, np.array([[2.0]]), np.zeros((1, 1, 1)))
    np.testing.assert_allclose(xn[0], [2.0, 1.0], rtol=1e-8)
    np.testing.assert_allclose(pn[0], np.zeros((2, 2)), atol=1e-8)
    assert ok.all()


def test_nis_matches_definition_and_chi2_mean():
    # For measurements drawn from N(Hx, S), NIS ~ chi2(d): mean d (here 3), variance 2d.
    # With 20000 rows the sample mean has standard error sqrt(6 / 20000) = 0.017;
    # accept within 5 standard errors.
    rng = np.random.default_rng(5)
    n_rows, d, n = 20000, 3, 6
    a = rng.standard_normal((n, n))
    p = np.broadcast_to(a @ a.T + np.eye(n), (n_rows, n, n)).copy()
    r = np.broadcast_to(np.diag([1.0, 2.0, 3.0]), (n_rows, d, d)).copy()
    x = np.zeros((n_rows, n))
    s = p[0, :d, :d] + r[0]
    z = rng.multivariate_normal(np.zeros(d), s, size=n_rows)
    _, _, nis, ok = kalman.update(x, p, z, r)
    assert ok.all()
    direct = np.einsum("ni,ij,nj->n", z, np.linalg.inv(s + kalman.S_FLOOR * np.eye(d)), z)
    np.testing.assert_allclose(nis, direct, rtol=1e-9)
    assert abs(nis.mean() - d) < 5 * np.sqrt(2 * d / n_rows)


def test_nis_alone_as_the_update_computes_it():
    """`nis_soa` (the IMM's NIS of the mixture, batch axis last) against the textbook
    nu' S^-1 nu and against the NIS of the full update on the same rows."""
    rng = np.random.default_rng(8)
    for d in (2, 3):
        k = 40
        a = rng.standard_normal((k, d, d))
        cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(d)
        r = np.broadcast_to(np.diag(rng.uniform(0.5, 2.0, d)), (k, d, d)).copy()
        pos, z = rng.standard_normal((k, d)), rng.standard_normal((k, d))
        nis = np.empty(k)
        kalman.nis_soa(pos.T.copy(), cov.transpose(1, 2, 0).copy(), z.T.copy(),
                       r.transpose(1, 2, 0).copy(), nis)
        s = cov + r + kalman.S_FLOOR * np.eye(d)
        nu = z - pos
        np.testing.assert_allclose(nis, np.einsum("ni,ni->n", nu, np.linalg.solve(
            s, nu[:, :, None])[:, :, 0]), rtol=1e-10)
        _, _, full, _ = kalman.update(pos, cov, z, r)
        np.testing.assert_allclose(nis, full, rtol=1e-12)


def test_non_finite_rows_flagged_by_ok_mask():
    # Rows 1..5 carry a NaN / inf somewhere; rows 0 and 6 are clean and must come out
    # exactly as if updated alone.
    n_rows, d = 7, 2
    x = np.tile([1.0, 2.0, 0.5, -0.5], (n_rows, 1))
    p = np.tile(np.diag([4.0, 4.0, 1.0, 1.0]), (n_rows, 1, 1))
    z = np.tile([2.0, 1.0], (n_rows, 1))
    r = np.tile(np.eye(d), (n_rows, 1, 1))
    z[1, 0] = np.nan
    z[2, 1] = np.inf
    x[3, 2] = np.nan
    r[4, 1, 1] = np.inf
    p[5, 0, 0] = np.nan
    with np.errstate(invalid="ignore", over="ignore"):
        xn, pn, nis, ok = kalman.update(x, p, z, r)
    assert ok.tolist() == [True, False, False, False, False, False, True]
    clean = kalman.update(x[:1], p[:1], z[:1], r[:1])
    for i in (0, 6):
        np.testing.assert_allclose(xn[i], clean[0][0], rtol=1e-12)
        np.testing.assert_allclose(pn[i], clean[1][0], rtol=1e-12)
        np.testing.assert_allclose(nis[i], clean[2][0], rtol=1e-12)
    # and every row the mask calls good is in fact finite
    assert np.isfinite(xn[ok]).all() and np.isfinite(pn[ok]).all() and np.isfinite(nis[ok]).all()


def test_symmetrise():
    p = np.array([[[1.0, 2.0], [4.0, 3.0]]])
    np.testing.assert_array_equal(kalman.symmetrise(p), [[[1.0, 3.0], [3.0, 3.0]]])


def test_singular_innovation_row_flagged_not_raised():
    # Row 0: P = 1e12 [[1, 1], [1, 1]], R = 0 -> S = P + 1e-9 I rounds to the singular
    # 1e12 [[1, 1], [1, 1]] (1e-9 is below half an ulp of 1e12). Row 1 is ordinary.
    x = np.zeros((2, 2))
    p = np.array([1e12 * np.ones((2, 2)), np.eye(2)])
    z = np.array([[1.0, 0.0], [1.0, 0.0]])
    r = np.array([np.zeros((2, 2)), np.eye(2)])
    xn, pn, nis, ok = kalman.update(x, p, z, r)
    assert ok.tolist() == [False, True]  # row 0 flagged (singular S), row 1 good
    # row 1 alone: S = 2 I, K = I/2 -> x = [0.5, 0], P = I/2, NIS = 1/2
    np.testing.assert_allclose(xn[1], [0.5, 0.0], rtol=1e-8)
    np.testing.assert_allclose(nis[1], 0.5, rtol=1e-8)
