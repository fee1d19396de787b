"""The fast batch-last kernels of zenoh_track.estimation against their textbook forms in
`reference`, on random rows and on the geometries where the fast forms take shortcuts
(the zenith, the horizon, the axes, the azimuth wrap-around, tight and broad
predictions).

Tolerance: every entry must agree to RTOL = 1e-9 relative, with an absolute floor of
RTOL times the largest entry of its row (a small entry of a matrix carries the rounding
of the large ones it is computed from). Each kernel also has a test that the same
comparison rejects a plausible mistake, so the agreement is not vacuous.

A limit of the textbook forms themselves is shown, not hidden: the textbook UCM
covariance is rounded to a few eps r^2 m^2 (so sensors here have saz >= 2 mrad and whole
steps ranges up to 40 km, with long ranges and precise sensors in a test of their own that
allows for that rounding explicitly). The cubature average uses the symmetric square root
of the covariance, so it does not depend on the eigenbasis where eigenvalues repeat
(test_expected_covariance_is_unique_where_an_eigenvalue_repeats).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from reference import estimation as reference

from zenoh_track.estimation import filters, kalman, linalg, models, polar, ucm
from zenoh_track.estimation.measurements import MeasurementBatch

RTOL = 1e-9
DIMS = [2, 3]


def rel_error(got: np.ndarray, want: np.ndarray) -> np.ndarray:
    """Per row, max |got - want| / (|want| + max |want| of the row): the comparison's
    measure (inf where only one of the two is NaN)."""
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    g, w = got.reshape(len(got), -1), want.reshape(len(want), -1)
    scale = np.abs(w).max(1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.abs(g - w) / (np.abs(w) + scale)
    err[(g == w) | (np.isnan(g) & np.isnan(w))] = 0.0  # equal, also zeros and NaN
    return np.where(np.isnan(err), np.inf, err).max(1)


def assert_close(got: np.ndarray, want: np.ndarray, what: str, **inputs: np.ndarray) -> None:
    err = rel_error(got, want)
    i = int(err.argmax())
    shown = {k: v[i] for k, v in inputs.items()}
    assert err[i] <= RTOL, (f"{what}: row {i} differs by {err[i]:.3g} relative\n"
                            f"fast {np.asarray(got)[i]!r}\nreference {np.asarray(want)[i]!r}\n"
                            f"input {shown!r}")


def soa(a: np.ndarray) -> np.ndarray:
    """Row-major (N, ...) -> contiguous batch-last (..., N)."""
    return np.ascontiguousarray(np.moveaxis(a, 0, -1))


def rows(a: np.ndarray) -> np.ndarray:
    return np.moveaxis(a, -1, 0)


def symmetric(a: np.ndarray) -> np.ndarray:
    """Exactly symmetric (the kernels' inputs are covariances)."""
    return 0.5 * (a + a.transpose(0, 2, 1))


def rotations(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(n, d, d)))
    return q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]


def spd_eig(rng: np.random.Generator, n: int, d: int, lo: float, hi: float) -> np.ndarray:
    """Random SPD (N, d, d) with eigenvalues log-uniform in [lo, hi] (m^2) and random
    eigenvectors; every tenth row has its two largest eigenvalues equal (the cubature's
    symmetric square root makes R unique there too)."""
    lam = np.exp(rng.uniform(math.log(lo), math.log(hi), (n, d)))
    lam.sort(1)
    lam[::10, -2] = lam[::10, -1]
    q = rotations(rng, n, d)
    return symmetric(np.einsum("nij,nj,nkj->nik", q, lam, q))


def spd_state(rng: np.random.Generator, n: int, order: int, dim: int) -> np.ndarray:
    """Realistic state covariances: random correlations, position std 3-60 m (P tens to
    thousands of m^2), velocity 1-30 m/s, acceleration 0.1-5 m/s^2."""
    k = order * dim
    a = rng.normal(size=(n, k, k))
    c = a @ a.transpose(0, 2, 1) + 0.2 * k * np.eye(k)
    c /= np.sqrt(np.einsum("nii->ni", c)[:, :, None] * np.einsum("nii->ni", c)[:, None, :])
    bounds = [(3.0, 60.0), (1.0, 30.0), (0.1, 5.0)][:order]
    std = np.concatenate([np.exp(rng.uniform(math.log(lo), math.log(hi), (n, dim)))
                          for lo, hi in bounds], 1)
    return symmetric(std[:, :, None] * c * std[:, None, :])


def from_polar(r: np.ndarray, az: np.ndarray, el: np.ndarray, d: int) -> np.ndarray:
    r, az, el = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, dtype=float))
                                      for v in (r, az, el)))
    return polar.polar_to_cartesian(r, az, el if d == 3 else None)


def noise(n: int, d: int, sr: float = 20.0, saz: float = 4e-3, sel: float = 5e-3):
    return (np.full(n, sr), np.full(n, saz), np.full(n, sel) if d == 3 else None)


# ------------------------------------------------------------------ prediction
@pytest.mark.parametrize("order", [2, 3])
def test_motion_matrices_match_models(order):
    dt = np.array([1.0, 0.0, -0.5, 2.5, -3.0, 1e-3])
    q = np.linspace(0.1, 5.0, len(dt))
    f, qm = reference.motion_matrices(dt, order, 3, q)
    assert_close(models.transition(dt, order, 3), f, "F", dt=dt)
    assert_close(models.process_noise(dt, order, 3, q), qm, "Q", dt=dt)
    if order == 2:  # CWNA of density q^2 |T| by hand for one axis
        t = 2.5
        np.testing.assert_allclose(qm[3][::3, ::3], q[3] ** 2 * t * np.array(
            [[t**3 / 3, t**2 / 2], [t**2 / 2, t]]))


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("order", [2, 3])
def test_predict_matches_reference(order, dim):
    rng = np.random.default_rng(10 * order + dim)
    n = 300
    x = np.concatenate([rng.uniform(-40e3, 40e3, (n, dim)), rng.uniform(-300, 300, (n, dim)),
                        rng.uniform(-20, 20, (n, dim))][:order], 1)
    p = spd_state(rng, n, order, dim)
    dt = rng.uniform(-5.0, 5.0, n)
    dt[:4] = [0.0, -0.5, 1e-3, -1e-3]
    q = rng.uniform(0.1, 10.0, n)
    xp, pp = models.predict(x, p, dt, order, dim, q)
    xr, pr = reference.predict(x, p, *reference.motion_matrices(dt, order, dim, q))
    assert_close(xp, xr, "x", dt=dt, x=x)
    assert_close(pp, pr, "P", dt=dt, p=p)
    assert np.array_equal(pp, pp.transpose(0, 2, 1))
    # scalar q: the same kernel
    ps = models.predict(x[:20], p[:20], dt[:20], order, dim, 2.0)[1]
    assert_close(ps, reference.predict(x[:20], p[:20], *reference.motion_matrices(
        dt[:20], order, dim, 2.0))[1], "P, scalar q")


def test_predict_comparison_rejects_signed_dt_noise():
    # Q built with the signed dt (instead of |dt|) flips the position-velocity noise of
    # the rows predicted backwards: far beyond the tolerance.
    rng = np.random.default_rng(3)
    n, order, dim = 100, 2, 3
    x = rng.uniform(-1e4, 1e4, (n, order * dim))
    p = spd_state(rng, n, order, dim)
    dt, q = rng.uniform(-3.0, -0.5, n), np.full(n, 3.0)
    pp = models.predict(x, p, dt, order, dim, q)[1]
    f, _ = reference.motion_matrices(dt, order, dim, q)
    g = np.stack([dt**2 / 2, dt], 1)
    wrong = models.expand(q[:, None, None] ** 2 * g[:, :, None] * g[:, None, :], dim)
    assert rel_error(pp, reference.predict(x, p, f, wrong)[1]).min() > 1e3 * RTOL


# ------------------------------------------------------------------ UCM, expected R
@pytest.mark.parametrize("d", DIMS)
def test_expected_ucm_matches_reference_random(d):
    rng = np.random.default_rng(20 + d)
    n = 300
    r, az, el = rng.uniform(1e3, 60e3, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(
        -0.05, 1.5, n)
    mean = from_polar(r, az, el, d)
    cov = spd_eig(rng, n, d, 10.0, 1e4)
    sr, saz = rng.uniform(5.0, 50.0, n), rng.uniform(2e-3, 1e-2, n)
    sel = rng.uniform(2e-3, 1e-2, n) if d == 3 else None
    az_meas = az + saz * rng.normal(size=n)
    got = ucm.ucm_covariance_expected(mean, cov, sr, saz, sel, az_meas)
    want = reference.ucm_covariance_expected(mean, cov, sr, saz, sel, az_meas)
    assert_close(got, want, "R", mean=mean, cov=cov, az_meas=az_meas)


def special_geometries(d: int, rng: np.random.Generator):
    """Sensor-relative means, measured azimuths and prediction covariances (tight, medium,
    broad, singular and zero; random and axis-aligned eigenvectors) at the kernel's
    special cases."""
    h, r = 9000.0, 15e3
    half = math.pi / 2
    pts, az_meas = [], []

    def add(p, a):
        pts.append(p[:d])
        az_meas.append(a)

    # the zenith (in 2-D: at the sensor), rho2 = 0, tiny and below the 1e-12 floor
    for xy in [(0.0, 0.0), (1e-3, -2e-3), (1e-7, 0.0), (30.0, 40.0)]:
        for a in (0.0, 2.5, -math.pi + 1e-3):
            add((*xy, h), a)
    add((0.0, 0.0, -3000.0), 1.0)  # straight below (el = -90 deg)
    # the horizon and slightly below it
    for el in (0.0, -1e-6, -0.01):
        p = from_polar(r, 0.7, el, 3)[0]
        add(p, 0.7 + 0.003)
    # on the axes (az = 0, pi/2, -pi/2, pi), at el = 0.2, and the wrap-around at +-pi
    for a in (0.0, half, -half, math.pi):
        p = from_polar(r, a, 0.2, 3)[0]
        p[np.abs(p) < 1e-9] = 0.0  # exactly on the axis
        add(p, a + 0.004)
        add(p, a - 0.004)
    for a, m in ((math.pi - 0.004, -math.pi + 0.004), (-math.pi + 0.004, math.pi - 0.004)):
        add(from_polar(r, a, 0.3, 3)[0], m)
        add(from_polar(800.0, a, 0.3, 3)[0], m)  # close: broad predictions straddle the sensor
    mean, az_meas = np.array(pts), np.array(az_meas)
    k = len(mean)
    covs = []
    for lam in ([1.0, 2.5, 4.0], [30.0, 300.0, 3000.0], [2e5, 6e5, 1e6], [0.0, 50.0, 2e3]):
        lam = np.array([lam[0], *lam[4 - d:]])  # the smallest and the d - 1 largest
        covs.append(np.broadcast_to(np.diag(lam), (k, d, d)))  # axis-aligned
        q = rotations(rng, k, d)
        covs.append(symmetric(np.einsum("nij,j,nkj->nik", q, lam, q)))
    covs.append(np.zeros((k, d, d)))  # all the points at the mean
    n_cov = len(covs)
    return (np.tile(mean, (n_cov, 1)), np.concatenate(covs), np.tile(az_meas, n_cov))


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("saz", [4e-3, 0.02])
def test_expected_ucm_matches_reference_special_geometries(d, saz):
    mean, cov, az_meas = special_geometries(d, np.random.default_rng(30 + d))
    sr, sa, sel = noise(len(mean), d, 20.0, saz, 1.5 * saz)
    got = ucm.ucm_covariance_expected(mean, cov, sr, sa, sel, az_meas)
    want = reference.ucm_covariance_expected(mean, cov, sr, sa, sel, az_meas)
    assert np.isfinite(want).all()
    assert_close(got, want, "R", mean=mean, cov=cov, az_meas=az_meas)


def test_expected_ucm_non_finite_covariance_gives_nan():
    mean = np.array([[1000.0, 2000.0, 300.0], [1000.0, 2000.0, 300.0]])
    cov = np.stack([np.eye(3) * 100.0, np.full((3, 3), np.nan)])
    args = (*noise(2, 3), np.array([0.5, 0.5]))
    got = ucm.ucm_covariance_expected(mean, cov, *args)
    want = reference.ucm_covariance_expected(mean, cov, *args)
    assert np.isnan(got[1]).all() and np.isnan(want[1]).all()
    assert_close(got, want, "R")


@pytest.mark.parametrize("d", DIMS)
def test_expected_ucm_comparison_rejects_r_at_the_mean_and_a_wrong_turn(d):
    # A broad prediction near the zenith (in 2-D near the sensor): R at the mean instead
    # of averaged, or averaged with the points' azimuths turned toward another azimuth
    # than the measured one, is far from the kernel.
    rng = np.random.default_rng(40 + d)
    n = 50
    mean = np.zeros((n, d))
    mean[:, :2] = rng.uniform(-100.0, 100.0, (n, 2))
    if d == 3:
        mean[:, 2] = 9000.0
    cov = spd_eig(rng, n, d, 1e4, 1e5)
    sr, saz, sel = noise(n, d)
    az_meas = rng.uniform(-np.pi, np.pi, n)
    got = ucm.ucm_covariance_expected(mean, cov, sr, saz, sel, az_meas)
    at_mean = polar.ucm_covariance(mean, sr, saz, sel)
    wrong_turn = reference.ucm_covariance_expected(mean, cov, sr, saz, sel, az_meas + 0.5)
    assert rel_error(got, at_mean).min() > 1e3 * RTOL
    assert rel_error(got, wrong_turn).min() > 1e3 * RTOL


def test_expected_covariance_is_unique_where_an_eigenvalue_repeats():
    # The cubature points are mean +- sqrt(d) times the columns of the symmetric square
    # root of the prediction's covariance, which (unlike its eigenvectors) is unique where
    # two eigenvalues coincide. With the points along the eigenvectors instead, splitting
    # a repeated eigenvalue (1e6 m^2) by 1 m^2 along two directions 45 deg apart in its
    # plane moved R by 1.4 %, and np.linalg.eigh and linalg.eigh, handed the degenerate
    # matrix itself, gave R 6e-4 apart. Now both splits and the degenerate matrix give
    # the same R to within the splitting's own effect, in both kernels.
    q = rotations(np.random.default_rng(5), 1, 3)[0]
    cov = q @ np.diag([1e4, 1e6, 1e6]) @ q.T
    mean, az_meas = np.array([[0.0, 3000.0, 2000.0]]), np.array([0.01])
    split = [cov + np.outer(u, u) for u in (q[:, 1], (q[:, 1] + q[:, 2]) / math.sqrt(2))]
    covs = np.stack([cov, *split])
    args = (*noise(3, 3), np.repeat(az_meas, 3))
    got = ucm.ucm_covariance_expected(np.repeat(mean, 3, 0), covs, *args)
    want = reference.ucm_covariance_expected(np.repeat(mean, 3, 0), covs, *args)
    assert_close(got, want, "R where an eigenvalue repeats")
    assert rel_error(want[1:], want[:1].repeat(2, 0)).max() < 1e-6
    assert rel_error(got[1:2], got[2:3])[0] < 1e-6
    # the comparison is not vacuous: points along one eigenbasis of the split matrix
    lam, v = np.linalg.eigh(split[0])
    pts = mean + np.concatenate([(v * np.sqrt(3 * lam)).T, -(v * np.sqrt(3 * lam)).T])
    r, az, el = polar.cartesian_to_polar(pts)
    w_turn = reference.ucm_covariance_expected(mean, split[0][None], *noise(1, 3), az_meas)
    along_vectors = polar.ucm_covariance_polar(r, az, el, *(np.full(6, v) for v in
                                                            (20.0, 4e-3, 5e-3))).mean(0)
    assert rel_error(along_vectors[None], w_turn)[0] > 1e-3


def measurements(rng: np.random.Generator, pos: np.ndarray, d: int, cart_every: int = 5
                 ) -> MeasurementBatch:
    """One measurement per target at pos (N, d) (common frame), from sensors within
    500 m of the origin; every `cart_every`-th Cartesian."""
    n = len(pos)
    origin = rng.uniform(-500.0, 500.0, (n, 3))
    rel = pos - origin[:, :d] + rng.normal(0.0, 20.0, (n, d))
    r, az, el = polar.cartesian_to_polar(rel)
    values = np.stack([r, az, el] if d == 3 else [r, az], 1)
    sigmas = np.tile([15.0, 0.004, 0.006][:d], (n, 1))
    is_polar = np.arange(n) % cart_every != cart_every - 1
    values[~is_polar] = pos[~is_polar] + rng.normal(0.0, 10.0, (int((~is_polar).sum()), d))
    sigmas[~is_polar] = [3.0, 4.0, 5.0][:d]
    return MeasurementBatch(np.zeros(n), is_polar, values, sigmas, origin)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("kind", ["polar", "mixed"])
def test_cmkf_conversion_matches_reference(d, kind):
    # cmkf_soa: all-polar batches go straight to _polar_soa, mixed ones split
    rng = np.random.default_rng(50 + d)
    n = 200
    pos = from_polar(rng.uniform(2e3, 60e3, n), rng.uniform(-np.pi, np.pi, n),
                     rng.uniform(0.0, 1.4, n), d)
    pos[:3, :2] = rng.uniform(-50.0, 50.0, (3, 2))  # nearly overhead
    cov = spd_eig(rng, n, d, 10.0, 1e4)
    batch = measurements(rng, pos, d, n + 1 if kind == "polar" else 5)
    assert batch.polar.all() == (kind == "polar")
    z, r = ucm.cmkf_arrays(batch, pos, cov)
    zr, rr = reference.cmkf_convert(batch, pos, cov)
    assert_close(z, zr, "z", values=batch.values, origin=batch.origin)
    assert_close(r, rr, "R", values=batch.values, pos=pos, cov=cov)
    # power: the plain (biased) conversion is off by r (1 - exp(-saz^2/2) ...) ~ 0.1 m
    pol = batch.polar
    plain = batch.origin[pol, :d] + polar.polar_to_cartesian(
        batch.values[pol, 0], batch.values[pol, 1], batch.values[pol, 2] if d == 3 else None)
    assert rel_error(z[pol], plain).min() > 1e3 * RTOL


# ------------------------------------------------------------------ Kalman update
def update_rows(rng: np.random.Generator, n: int, order: int, dim: int):
    x = np.concatenate([rng.uniform(-40e3, 40e3, (n, dim)),
                        rng.uniform(-300, 300, (n, (order - 1) * dim))], 1)
    p = spd_state(rng, n, order, dim)
    r = spd_eig(rng, n, dim, 10.0, 1e4)
    z = x[:, :dim] + rng.normal(0.0, 50.0, (n, dim))
    p[0], r[0] = 0.0, 0.0  # exact measurement of a known position: the S_FLOOR case
    p[1] *= 1e3  # prediction much broader than the measurement
    r[2] *= 1e3  # and much narrower
    return x, p, z, r


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("order", [2, 3])
def test_joseph_update_matches_reference(order, dim):
    rng = np.random.default_rng(60 + 10 * order + dim)
    x, p, z, r = update_rows(rng, 300, order, dim)
    xn, pn, nis, ok, ll = kalman.update_full(x, p, z, r)
    xr, pr, nisr, detr = reference.joseph_update(x, p, z, r)
    assert ok.all()
    assert_close(xn, xr, "x", x=x, p=p, z=z, r=r)
    assert_close(pn, pr, "P", x=x, p=p, z=z, r=r)
    assert_close(nis, nisr, "NIS", x=x, p=p, z=z, r=r)
    assert_close(ll, -0.5 * (nisr + np.log(detr) + dim * np.log(2 * np.pi)), "loglik")
    # the kernel itself, batch-last, for det S
    xs, det = soa(x), np.empty(len(x))
    p_out, nis2 = np.empty(p.shape[1:] + (len(x),)), np.empty(len(x))
    kalman.update_soa(xs, soa(p), soa(z), soa(r), p_out, nis2, det)
    assert_close(det, detr, "det S", p=p, r=r)
    assert_close(xs.T, xr, "x (update_soa)")
    assert_close(rows(p_out), pr, "P (update_soa)")


def test_joseph_comparison_rejects_the_wrong_r():
    # The reference updated with the R of another row is far from the kernel.
    x, p, z, r = update_rows(np.random.default_rng(7), 100, 2, 3)
    pn = kalman.update(x, p, z, r)[1]
    wrong = reference.joseph_update(x, p, z, np.roll(r, 1, axis=0))[1]
    assert np.median(rel_error(pn, wrong)) > 1e3 * RTOL


# ------------------------------------------------------------------ linear algebra
def eigen_cases(rng: np.random.Generator, d: int) -> np.ndarray:
    """Random realistic covariances, diagonal ones, nearly and exactly repeated
    eigenvalues, a rank-one matrix and zero."""
    cov = [spd_eig(rng, 200, d, 1.0, 1e6)]
    cov.append(np.array([np.diag(v) for v in rng.uniform(1.0, 1e4, (20, d))]))
    q = rotations(rng, 40, d)
    for gap in (0.0, 1e-12, 1e-9, 1e-6):
        lam = np.array([400.0, 400.0 * (1 + gap), 25.0][:d])
        cov.append(symmetric(np.einsum("nij,j,nkj->nik", q[:10], lam, q[:10])))
    v = rng.normal(size=(5, d)) * 100.0
    cov.append(v[:, :, None] * v[:, None, :])
    cov.append(np.zeros((1, d, d)))
    return np.concatenate(cov)


def eigen_projectors(vals: np.ndarray, vecs: np.ndarray, lam_max: float) -> list:
    """(lo, hi, projector onto the span) of each cluster of ascending eigenvalues within
    1e-4 lam_max of each other: an eigenvector is determined only to about
    eps lam_max / gap (Golub & Van Loan 2013, sec. 8.1), the span of a cluster is."""
    out, start = [], 0
    for k in range(1, len(vals) + 1):
        if k == len(vals) or vals[k] - vals[k - 1] > 1e-4 * lam_max:
            v = vecs[:, start:k]
            out.append((start, k, v @ v.T))
            start = k
    return out


def check_eigh(cov: np.ndarray, vals: list, vecs: list) -> float:
    """Largest relative deviation of linalg.eigh's pairs from reference.eigh's, compared
    as sets: sorted eigenvalues, projectors of clusters, residuals, orthonormality."""
    d = cov.shape[1]
    lam = np.array(vals).T  # (N, d)
    v = np.stack([np.asarray(x).T for x in vecs], 2)  # (N, d, d), columns
    order = np.argsort(lam, 1)
    lam = np.take_along_axis(lam, order, 1)
    v = np.take_along_axis(v, order[:, None, :], 2)
    want_lam, want_v = reference.eigh(cov)
    worst = 0.0
    for i in range(len(cov)):
        top = max(np.abs(want_lam[i]).max(), 1e-300)
        worst = max(worst, np.abs(lam[i] - want_lam[i]).max() / top)
        worst = max(worst, np.abs(v[i].T @ v[i] - np.eye(d)).max())
        worst = max(worst, np.abs(cov[i] @ v[i] - v[i] * lam[i]).max() / top)
        for lo, hi, proj in eigen_projectors(want_lam[i], want_v[i], top):
            mine = v[i][:, lo:hi] @ v[i][:, lo:hi].T
            worst = max(worst, np.abs(mine - proj).max())
    return worst


@pytest.mark.parametrize("d", DIMS)
def test_eigh_matches_reference(d):
    cov = eigen_cases(np.random.default_rng(70 + d), d)
    vals, vecs = linalg.eigh(soa(cov), d)
    assert check_eigh(cov, vals, vecs) <= RTOL


def test_eigh_comparison_rejects_swapped_axes():
    cov = spd_eig(np.random.default_rng(8), 50, 3, 1.0, 1e6)
    vals, vecs = linalg.eigh(soa(cov), 3)
    swapped = [np.asarray(vecs[k])[[1, 0, 2]] for k in range(3)]
    assert check_eigh(cov, vals, swapped) > 1e3 * RTOL


@pytest.mark.parametrize("m", [1, 2, 3])
@pytest.mark.parametrize("floor", [0.0, kalman.S_FLOOR])
def test_ldl_solve_and_inverse_match_reference(m, floor):
    rng = np.random.default_rng(80 + m)
    n = 300
    s = spd_eig(rng, n, m, 10.0, 1e5) if m > 1 else rng.uniform(10.0, 1e5, (n, 1, 1))
    if floor:
        s[0] = 0.0  # singular without the floor
    b = rng.normal(0.0, 1e3, (n, m, 4))
    lower = soa(s)
    for i in range(m):  # only the lower triangle is read
        lower[i, i + 1:] = np.nan
    sol, det = soa(b), np.empty(n)
    linalg.ldl_solve(lower, sol, det, floor)
    want, want_det = reference.ldl_solve(s, b, floor)
    assert_close(rows(sol), want, "S^-1 b", s=s, b=b)
    assert_close(det, want_det, "det S", s=s)
    inv, det2 = np.empty((m, m, n)), np.empty(n)
    linalg.ldl_inverse(lower, inv, det2, floor)
    want_inv, _ = reference.ldl_inverse(s, floor)
    assert_close(rows(inv), want_inv, "S^-1", s=s)
    assert_close(det2, want_det, "det S (inverse)", s=s)


def test_ldl_comparison_rejects_the_other_sign():
    # the reference of S with its off-diagonal entries negated is far from the kernel
    s = spd_eig(np.random.default_rng(9), 100, 3, 10.0, 1e5)
    inv, det = np.empty((3, 3, 100)), np.empty(100)
    linalg.ldl_inverse(soa(s), inv, det)
    flip = s * (2 * np.eye(3) - 1)
    assert rel_error(rows(inv), reference.ldl_inverse(flip)[0]).min() > 1e3 * RTOL


# ------------------------------------------------------------------ the whole step
def step_scene(rng: np.random.Generator, n: int, order: int, dim: int,
               ranges: tuple[float, float] = (2e3, 40e3)):
    """Priors, dt and measurements of targets at `ranges` (m); up to 40 km the textbook
    R's rounding stays well below RTOL of the posterior (see
    test_long_range_agrees_to_the_rounding_of_the_textbook_covariance)."""
    pos = from_polar(rng.uniform(*ranges, n), rng.uniform(-np.pi, np.pi, n),
                     rng.uniform(0.02, 1.4, n), dim)
    pos[:3, :2] = rng.uniform(-50.0, 50.0, (3, 2))  # nearly overhead
    vel = rng.normal(0.0, 150.0, (n, dim))
    x = np.concatenate([pos, vel, np.zeros((n, dim))][:order], 1)
    p = spd_state(rng, n, order, dim)
    dt = rng.uniform(0.5, 2.0, n)
    dt[:5] = -dt[:5]  # predicted backwards
    return x, p, dt, measurements(rng, pos + vel * dt[:, None], dim)


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("order", [2, 3])
def test_cmkf_step_matches_reference(order, dim):
    x, p, dt, batch = step_scene(np.random.default_rng(90 + 10 * order + dim), 200, order, dim)
    xn, pn, nis, ok = filters.cmkf_step(x, p, dt, order, dim, 0.7, batch)
    xr, pr, nisr = reference.cmkf_step(x, p, dt, order, dim, 0.7, batch)
    assert ok.all()
    assert_close(xn, xr, "x", x=x, p=p, dt=dt, values=batch.values)
    assert_close(pn, pr, "P", x=x, p=p, dt=dt, values=batch.values)
    assert_close(nis, nisr, "NIS", x=x, p=p, dt=dt, values=batch.values)


def test_cmkf_step_comparison_rejects_r_at_the_prediction():
    # The reference with R evaluated at the predicted mean (a zero prediction covariance
    # in the conversion) instead of averaged over the prediction.
    order, dim = 2, 3
    x, p, dt, batch = step_scene(np.random.default_rng(11), 100, order, dim)
    p[:, :dim, :dim] *= 100.0  # broad predictions (std 30-600 m)
    pn = filters.cmkf_step(x, p, dt, order, dim, 0.7, batch)[1]
    xp, pp = reference.predict(x, p, *reference.motion_matrices(dt, order, dim, 0.7))
    z, r = reference.cmkf_convert(batch, xp[:, :dim], 0.0 * pp[:, :dim, :dim])
    wrong = reference.joseph_update(xp, pp, z, r)[1]
    assert np.median(rel_error(pn[batch.polar], wrong[batch.polar])) > 1e3 * RTOL


@pytest.mark.parametrize("dim", DIMS)
def test_long_range_agrees_to_the_rounding_of_the_textbook_covariance(dim):
    # The textbook UCM covariance (Mo et al. 1998: E[z z'] - p p', polar.ucm_covariance_polar)
    # cancels terms of order r^2 to leave about r^2 saz^2 + sr^2, so it is rounded to a few
    # eps r^2 (m^2): relative to R, eps r^2 / (r^2 saz^2 + sr^2), 1e-11 for the sensors
    # above (saz >= 2 mrad) but up to 1e-9 for precise ones (saz <= 0.5 mrad), and the
    # update amplifies it along the range, where R is only sr^2: ~1e-8 of the posterior
    # at 100-200 km. The fast kernel regroups those terms (ucm._ucm_sums_2d/_3d) and is
    # the accurate one (1e-13 against an extended-precision evaluation of the same
    # formula). So at long range and with precise sensors R is compared with an explicit
    # allowance for the reference's rounding, 4 eps (|mean|^2 + tr cov) m^2 (the largest
    # seen is 1.6), and the rest of the step with the kernel's own R, to RTOL.
    rng = np.random.default_rng(100 + dim)
    n = 200
    x, p, dt, batch = step_scene(rng, n, 2, dim, (100e3, 200e3))
    batch.sigmas[batch.polar, 0] = rng.uniform(5.0, 20.0, int(batch.polar.sum()))
    batch.sigmas[batch.polar, 1:] = rng.uniform(1e-4, 1e-3, (int(batch.polar.sum()), dim - 1))
    xp, pp = reference.predict(x, p, *reference.motion_matrices(dt, 2, dim, 0.7))
    z, r = ucm.cmkf_arrays(batch, xp[:, :dim], pp[:, :dim, :dim])
    zr, rr = reference.cmkf_convert(batch, xp[:, :dim], pp[:, :dim, :dim])
    assert_close(z, zr, "z")
    rel = xp[:, :dim] - batch.origin[:, :dim]
    allowance = 4 * np.finfo(float).eps * (np.einsum("ni,ni->n", rel, rel)
                                           + np.trace(pp[:, :dim, :dim], axis1=1, axis2=2))
    scale = np.abs(rr).max((1, 2), keepdims=True)
    excess = np.abs(r - rr) - RTOL * (np.abs(rr) + scale) - allowance[:, None, None]
    assert excess.max() <= 0, int(excess.max((1, 2)).argmax())
    xn, pn, nis, ok = filters.cmkf_step(x, p, dt, 2, dim, 0.7, batch)
    xr, pr, nisr, _ = reference.joseph_update(xp, pp, z, r)
    assert ok.all()
    assert_close(xn, xr, "x")
    assert_close(pn, pr, "P")
    assert_close(nis, nisr, "NIS")

