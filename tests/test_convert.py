"""Unit tests of zenoh_track.convert: geometry of the compass convention and a Monte Carlo
check of the unbiased converted measurement (UCM) and its error covariance.

Monte Carlo tolerances: with N = 200 000 independent samples of the conversion error
e = z_u - p (p the true sensor-relative position), each estimate below is a sample mean
of i.i.d. terms (e_i for the bias, e_i e_j for the covariance, which is the second
moment because the UCM has zero mean), so by the CLT its standard error is
std(term) / sqrt(N), estimated from the same samples. Each entry must lie within
K_SE = 5 standard errors of the formula (two-sided false-alarm probability 6e-7 per
entry). The same criterion is shown to reject the plain (biased) conversion and an
x/y-swapped covariance, so it has power.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from zenoh_track.estimation import polar, ucm

N_MC = 200_000
K_SE = 5.0

# (r, az, el, sr, saz, sel): compass azimuth from North (+y) clockwise, radians.
GEOMETRIES_3D = [
    pytest.param(10_000.0, 0.3, 0.2, 50.0, 0.05, 0.05, id="NE-low"),
    pytest.param(10_000.0, 2.5, math.radians(85.0), 50.0, 0.05, 0.05, id="SE-el85"),
    pytest.param(8_000.0, -2.0, -0.3, 30.0, 0.08, 0.04, id="SW-below"),
    pytest.param(5_000.0, -0.7, 1.0, 20.0, 0.10, 0.10, id="NW-high-noise"),
    pytest.param(12_000.0, math.pi / 2, math.radians(84.0), 40.0, 0.06, 0.03, id="E-el84"),
]
GEOMETRIES_2D = [
    pytest.param(10_000.0, 0.3, 50.0, 0.05, id="NE"),
    pytest.param(3_000.0, 2.2, 30.0, 0.10, id="SE"),
    pytest.param(6_000.0, -2.5, 30.0, 0.07, id="SW"),
    pytest.param(7_000.0, -1.0, 10.0, 0.08, id="NW"),
]


def _draw(seed, r, az, el, sr, saz, sel):
    """True sensor-relative point (1, d) and N noisy polar measurements."""
    rng = np.random.default_rng(seed)
    rm = r + sr * rng.standard_normal(N_MC)
    am = az + saz * rng.standard_normal(N_MC)
    if el is None:
        truth = np.array([[r * math.sin(az), r * math.cos(az)]])
        return truth, rm, am, None
    em = el + sel * rng.standard_normal(N_MC)
    ce = math.cos(el)
    truth = np.array([[r * ce * math.sin(az), r * ce * math.cos(az), r * math.sin(el)]])
    return truth, rm, am, em


def _mean_z(err):
    """Sample mean of each component divided by its standard error."""
    return err.mean(0) / (err.std(0) / math.sqrt(N_MC))


def _cov_z(err, cov):
    """(sample second moment - cov) / standard error, per entry."""
    prod = err[:, :, None] * err[:, None, :]
    return (prod.mean(0) - cov) / (prod.std(0) / math.sqrt(N_MC))


def _swap_xy(cov):
    idx = [1, 0, *range(2, cov.shape[0])]
    return cov[np.ix_(idx, idx)]


@pytest.mark.parametrize(("r", "az", "el", "sr", "saz", "sel"), GEOMETRIES_3D)
def test_ucm_3d_unbiased_and_covariance(r, az, el, sr, saz, sel):
    truth, rm, am, em = _draw(1, r, az, el, sr, saz, sel)
    z = polar.unbiased(rm, am, em, np.full(N_MC, saz), np.full(N_MC, sel))
    err = z - truth
    cov = polar.ucm_covariance(truth, np.array([sr]), np.array([saz]), np.array([sel]))[0]

    assert np.abs(_mean_z(err)).max() < K_SE, _mean_z(err)
    zc = _cov_z(err, cov)
    assert np.abs(zc).max() < K_SE, zc
    assert np.array_equal(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() > 0

    # Power: the plain conversion is biased by p (1 - lb le) along x, y (p (1 - le) in z)
    # with these angle noises, and the compass/math x-y swap is visibly wrong.
    plain = polar.polar_to_cartesian(rm, am, em) - truth
    assert np.abs(_mean_z(plain)).max() > K_SE
    assert np.abs(_cov_z(err, _swap_xy(cov))).max() > K_SE


@pytest.mark.parametrize(("r", "az", "sr", "saz"), GEOMETRIES_2D)
def test_ucm_2d_unbiased_and_covariance(r, az, sr, saz):
    truth, rm, am, _ = _draw(2, r, az, None, sr, saz, None)
    z = polar.unbiased(rm, am, None, np.full(N_MC, saz), None)
    assert z.shape == (N_MC, 2)
    err = z - truth
    cov = polar.ucm_covariance(truth, np.array([sr]), np.array([saz]), None)[0]
    assert cov.shape == (2, 2)

    assert np.abs(_mean_z(err)).max() < K_SE, _mean_z(err)
    zc = _cov_z(err, cov)
    assert np.abs(zc).max() < K_SE, zc

    plain = polar.polar_to_cartesian(rm, am, None) - truth
    assert np.abs(_mean_z(plain)).max() > K_SE
    assert np.abs(_cov_z(err, _swap_xy(cov))).max() > K_SE


def test_ucm_covariance_vectorised_over_rows():
    # Row i of a batch call equals the single-row call.
    pts = np.array([[1000.0, 2000.0, 300.0], [-500.0, -10.0, 8000.0], [3.0, -4000.0, -200.0]])
    sr, saz, sel = np.array([10.0, 20.0, 5.0]), np.array([0.01, 0.02, 0.03]), np.array(
        [0.02, 0.01, 0.005])
    batch = polar.ucm_covariance(pts, sr, saz, sel)
    for i in range(3):
        one = polar.ucm_covariance(pts[i:i + 1], sr[i:i + 1], saz[i:i + 1], sel[i:i + 1])
        np.testing.assert_allclose(batch[i], one[0], rtol=1e-12)


def test_ucm_small_noise_limit_is_linearised_covariance():
    # For small angle noise, the UCM covariance tends to J diag(sr^2, saz^2, sel^2) J'
    # with J the Jacobian of (r, az, el) -> (x, y, z):
    #   dx/dr = cos el sin az, dx/daz = r cos el cos az, dx/del = -r sin el sin az
    #   dy/dr = cos el cos az, dy/daz = -r cos el sin az, dy/del = -r sin el cos az
    #   dz/dr = sin el,        dz/daz = 0,                dz/del = r cos el
    r, az, el = 5000.0, 2.0, 0.4
    sr, saz, sel = 5.0, 1e-4, 2e-4
    ce, se, ca, sa = math.cos(el), math.sin(el), math.cos(az), math.sin(az)
    jac = np.array([
        [ce * sa, r * ce * ca, -r * se * sa],
        [ce * ca, -r * ce * sa, -r * se * ca],
        [se, 0.0, r * ce],
    ])
    lin = jac @ np.diag([sr**2, saz**2, sel**2]) @ jac.T
    p = np.array([[r * ce * sa, r * ce * ca, r * se]])
    cov = polar.ucm_covariance(p, np.array([sr]), np.array([saz]), np.array([sel]))[0]
    # Entries are O(1) m^2 while the terms subtracted are O(r^2) = 2.5e7 m^2, so the
    # comparison is limited by cancellation (~1e-16 * 2.5e7 * few) and O(s^2) terms.
    np.testing.assert_allclose(cov, lin, rtol=1e-3, atol=1e-3)


# ---------------------------------------------------------------- geometry
def test_compass_axes():
    # az = 0 is North (+y), az = pi/2 East (+x), el = pi/2 straight up (+z).
    r = np.array([100.0, 100.0, 100.0, 100.0])
    az = np.array([0.0, math.pi / 2, math.pi, 0.0])
    el = np.array([0.0, 0.0, 0.0, math.pi / 2])
    p = polar.polar_to_cartesian(r, az, el)
    np.testing.assert_allclose(p, [[0, 100, 0], [100, 0, 0], [0, -100, 0], [0, 0, 100]],
                               atol=1e-12)
    p2 = polar.polar_to_cartesian(r[:3], az[:3], None)
    np.testing.assert_allclose(p2, [[0, 100], [100, 0], [0, -100]], atol=1e-12)


def test_polar_to_cartesian_matches_protocol_formula():
    # x = r cos(el) sin(az), y = r cos(el) cos(az), z = r sin(el), all quadrants.
    rng = np.random.default_rng(9)
    r = rng.uniform(1.0, 1e5, 1000)
    az = rng.uniform(-math.pi, math.pi, 1000)
    el = rng.uniform(-1.5, 1.5, 1000)
    p = polar.polar_to_cartesian(r, az, el)
    expected = np.stack([r * np.cos(el) * np.sin(az), r * np.cos(el) * np.cos(az),
                         r * np.sin(el)], -1)
    np.testing.assert_allclose(p, expected, rtol=1e-13, atol=1e-9)
    p2 = polar.polar_to_cartesian(r, az, None)
    np.testing.assert_allclose(p2, np.stack([r * np.sin(az), r * np.cos(az)], -1),
                               rtol=1e-13, atol=1e-9)


def test_round_trip_3d_and_2d():
    rng = np.random.default_rng(10)
    r = rng.uniform(1.0, 1e5, 1000)
    az = rng.uniform(-math.pi + 1e-6, math.pi, 1000)  # arctan2 range (-pi, pi]
    el = rng.uniform(-1.55, 1.55, 1000)
    r2, az2, el2 = polar.cartesian_to_polar(polar.polar_to_cartesian(r, az, el))
    np.testing.assert_allclose(r2, r, rtol=1e-12)
    np.testing.assert_allclose(az2, az, atol=1e-9)
    np.testing.assert_allclose(el2, el, atol=1e-12)
    r3, az3, el3 = polar.cartesian_to_polar(polar.polar_to_cartesian(r, az, None))
    assert el3 is None
    np.testing.assert_allclose(r3, r, rtol=1e-12)
    np.testing.assert_allclose(az3, az, atol=1e-12)


def test_cartesian_to_polar_hand_values():
    # (3, 4, 12): r = 13; az = atan2(x=3, y=4) (east of north); el = atan2(12, 5).
    # (-1, -1): south-west, az = -3 pi / 4.
    r, az, el = polar.cartesian_to_polar(np.array([[3.0, 4.0, 12.0]]))
    np.testing.assert_allclose(r, [13.0])
    np.testing.assert_allclose(az, [math.atan2(3.0, 4.0)])
    np.testing.assert_allclose(el, [math.atan2(12.0, 5.0)])
    r, az, el = polar.cartesian_to_polar(np.array([[-1.0, -1.0]]))
    np.testing.assert_allclose(r, [math.sqrt(2.0)])
    np.testing.assert_allclose(az, [-3 * math.pi / 4])
    assert el is None


def test_unbiased_divides_by_bias_factors():
    # lb = exp(-saz^2/2), le = exp(-sel^2/2): x, y divided by lb le, z by le.
    r, az, el, saz, sel = 1000.0, 0.5, 0.3, 0.2, 0.1
    lb, le = math.exp(-0.02), math.exp(-0.005)
    z = polar.unbiased(np.array([r]), np.array([az]), np.array([el]), np.array([saz]),
                         np.array([sel]))[0]
    ce = math.cos(el)
    np.testing.assert_allclose(z, [r * ce * math.sin(az) / (lb * le),
                                   r * ce * math.cos(az) / (lb * le),
                                   r * math.sin(el) / le], rtol=1e-13)
    z2 = polar.unbiased(np.array([r]), np.array([az]), None, np.array([saz]), None)[0]
    np.testing.assert_allclose(z2, [r * math.sin(az) / lb, r * math.cos(az) / lb], rtol=1e-13)


def test_expected_covariance_tends_to_r_at_mean_for_a_tight_prediction():
    # With a prediction much tighter than the measurement, the average over the prediction
    # equals R at the predicted point (the decorrelated UCM of Bordonaro et al.).
    p = np.array([[3000.0, -8000.0, 4000.0]])
    args = (np.array([50.0]), np.array([0.01]), np.array([0.01]))
    r0 = polar.ucm_covariance(p, *args)
    r1 = ucm.ucm_covariance_expected(p, np.eye(3)[None] * 1e-4, *args,
                                         np.array([2.0]))
    np.testing.assert_allclose(r1, r0, rtol=1e-6)


def test_expected_covariance_near_zenith_matches_monte_carlo():
    # Overhead with a wide prediction: the conversion error covariance given the measured
    # azimuth is oriented by that azimuth. Monte Carlo: truths drawn from the prediction,
    # measured, and binned by measured azimuth near 30 deg; the cubature R must be close to
    # the sample covariance of those errors (within 10 % of the error scale).
    rng = np.random.default_rng(3)
    n = 400_000
    mean = np.array([0.0, 0.0, 10_000.0])
    cov = np.diag([60.0**2, 60.0**2, 10.0**2])
    truth = mean + rng.standard_normal((n, 3)) @ np.sqrt(cov)
    sr, sa = 50.0, np.radians(0.5)
    r, az, el = polar.cartesian_to_polar(truth)
    rm, am, em = (r + sr * rng.standard_normal(n), az + sa * rng.standard_normal(n),
                  el + sa * rng.standard_normal(n))
    z = polar.unbiased(rm, am, em, np.full(n, sa), np.full(n, sa))
    sel = np.abs(np.angle(np.exp(1j * (am - np.radians(30))))) < np.radians(2)
    err = (z - truth)[sel]
    mc = np.cov(err.T)
    got = ucm.ucm_covariance_expected(mean[None], cov[None], np.array([sr]),
                                          np.array([sa]), np.array([sa]),
                                          np.array([np.radians(30)]))[0]
    scale = np.sqrt(np.trace(mc))
    assert np.abs(got - mc).max() < 0.10 * scale**2 / 3
