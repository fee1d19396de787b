"""The compiled conversion at the measured points against its NumPy reference
(`ucm.cmkf_arrays(batch, None)`), and its dispatch (`gate_jit.at_point`)."""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_track.estimation import gate_jit, jit
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.estimation.ucm import cmkf_arrays


def batch(rng: np.random.Generator, n: int, d: int, polar: np.ndarray) -> MeasurementBatch:
    """n detections of dimension d, polar where `polar` (ranges 1-300 km, elevations up
    to the zenith, noise from 1 m and 0.1 mrad to 200 m and 50 mrad), from sensors
    anywhere."""
    values = np.empty((n, d), order="F")
    sigmas = np.empty((n, d), order="F")
    values[:, 0] = rng.uniform(1e3, 3e5, n)
    values[:, 1] = rng.uniform(-np.pi, np.pi, n)
    sigmas[:, 0] = rng.uniform(1.0, 200.0, n)
    sigmas[:, 1] = rng.uniform(1e-4, 0.05, n)
    if d == 3:
        values[:, 2] = rng.uniform(-0.1, np.pi / 2, n)
        sigmas[:, 2] = rng.uniform(1e-4, 0.05, n)
    cart = ~polar
    values[cart] = rng.normal(0.0, 5e4, (int(cart.sum()), d))
    sigmas[cart] = rng.uniform(1.0, 100.0, (int(cart.sum()), d))
    return MeasurementBatch(rng.uniform(0, 10, n), polar, values, sigmas,
                            rng.normal(0.0, 1e4, (n, 3)))


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("kind", ["polar", "cartesian", "mixed"])
def test_compiled_matches_the_numpy_form(d, kind):
    rng = np.random.default_rng(d * 7 + len(kind))
    n = 257
    polar = {"polar": np.ones(n, bool), "cartesian": np.zeros(n, bool),
             "mixed": rng.random(n) < 0.5}[kind]
    b = batch(rng, n, d, polar)
    z0, r0 = cmkf_arrays(b, None)
    z1, r1 = gate_jit.compiled(b)
    # R is a difference of terms of the order of range^2 (the rounding's scale)
    scale = np.where(polar, b.values[:, 0] ** 2, np.abs(r0).max(axis=(1, 2)))[:, None, None]
    assert np.allclose(z1, z0, rtol=1e-12, atol=1e-9)
    assert np.all(np.abs(r1 - r0) <= 1e-14 * scale)
    assert np.array_equal(r1[~polar], r0[~polar])
    assert np.array_equal(r1, np.transpose(r1, (0, 2, 1)))  # symmetric, as the reference


def test_dispatch_keeps_the_conversion_on_the_batch():
    """Computed once a batch (gating and initiation share it); by the kernel once the
    kernels serve, by NumPy before."""
    jit.load([gate_jit])
    rng = np.random.default_rng(3)
    b = batch(rng, 9, 3, np.ones(9, bool))
    first = gate_jit.at_point(b)
    assert gate_jit.at_point(b) is first and b.point is first
    assert np.allclose(first[0], cmkf_arrays(b, None)[0], rtol=1e-12)
    empty = batch(rng, 0, 3, np.zeros(0, bool))
    z, r = gate_jit.at_point(empty)
    assert z.shape == (0, 3) and r.shape == (0, 3, 3)


def pairs_problem(rng: np.random.Generator, d: int, tracks: int, dets: int, k: int):
    """k pairs of `tracks` predicted tracks (mean_s (d, T), cross_s (d, 3d, T) with a
    positive definite position block) and `dets` detections (z, R)."""
    n = 3 * d
    a = rng.normal(0.0, 30.0, (tracks, n, n))
    p = a @ a.transpose(0, 2, 1) + np.eye(n) * 10.0  # (T, n, n) positive definite
    cross_s = np.ascontiguousarray(p[:, :d, :].transpose(1, 2, 0))
    mean_s = rng.normal(0.0, 1e4, (d, tracks))
    b = rng.normal(0.0, 20.0, (dets, d, d))
    r = b @ b.transpose(0, 2, 1) + np.eye(d)
    z = rng.normal(0.0, 1e4, (dets, d))
    return (rng.integers(0, tracks, k), rng.integers(0, dets, k), z, mean_s, cross_s, r,
            p[:, :d, :d])


@pytest.mark.parametrize("d", [2, 3])
def test_gate_pairs_match_the_numpy_form(d):
    from zenoh_track.tracking.gating import pair_distances

    ti, dj, z, mean_s, cross_s, r, _ = pairs_problem(np.random.default_rng(d), d, 40, 30, 500)
    nu0, d20, det0 = pair_distances(ti, dj, z, mean_s, cross_s, r)
    nu1, d21, det1 = gate_jit.gate_pairs(ti, dj, z, mean_s, cross_s, r)
    assert np.array_equal(nu1, nu0)
    np.testing.assert_allclose(d21, d20, rtol=1e-11)
    np.testing.assert_allclose(det1, det0, rtol=1e-11)
    singular = cross_s.copy()
    singular[:, :d] = 0.0  # S = 0: the first pivot zero
    _, d2s, dets = gate_jit.gate_pairs(ti[:3], dj[:3], z, mean_s, singular, np.zeros_like(r))
    assert np.isnan(d2s).all() and (dets == 0).all()


@pytest.mark.parametrize("d", [2, 3])
def test_mixture_matches_the_numpy_form(d):
    from zenoh_track.estimation.imm import IMM

    rng = np.random.default_rng(10 + d)
    ti, dj, z, mean_s, cross_s, r, narrow = pairs_problem(rng, d, 40, 30, 500)
    nu = rng.normal(0.0, 50.0, (len(ti), d))
    loglik = rng.normal(-20.0, 5.0, len(ti))
    loglik[:5] = -np.inf  # the widest mode rules a pair out
    w = rng.uniform(0.01, 1.0, 40)
    w[ti[:3]] = 1.0  # the widest mode alone
    plain = IMM.pair_likelihood(None, loglik, ti, nu, r[dj], narrow, w)  # type: ignore[arg-type]
    fast = gate_jit.mixture(loglik, ti, nu, r[dj], narrow, w)
    finite = np.isfinite(plain)
    assert np.array_equal(finite, np.isfinite(fast))
    np.testing.assert_allclose(fast[finite], plain[finite], rtol=1e-12, atol=1e-9)
