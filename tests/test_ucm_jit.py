"""The compiled conversion at the measured points against its NumPy reference
(`ucm.cmkf_arrays(batch, None)`), and its dispatch (`ucm_jit.at_point`)."""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_track.estimation import jit, ucm_jit
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
    z1, r1 = ucm_jit.compiled(b)
    # R is a difference of terms of the order of range^2 (the rounding's scale)
    scale = np.where(polar, b.values[:, 0] ** 2, np.abs(r0).max(axis=(1, 2)))[:, None, None]
    assert np.allclose(z1, z0, rtol=1e-12, atol=1e-9)
    assert np.all(np.abs(r1 - r0) <= 1e-14 * scale)
    assert np.array_equal(r1[~polar], r0[~polar])
    assert np.array_equal(r1, np.transpose(r1, (0, 2, 1)))  # symmetric, as the reference


def test_dispatch_keeps_the_conversion_on_the_batch():
    """Computed once a batch (gating and initiation share it); by the kernel once the
    kernels serve, by NumPy before."""
    jit.load([ucm_jit])
    rng = np.random.default_rng(3)
    b = batch(rng, 9, 3, np.ones(9, bool))
    first = ucm_jit.at_point(b)
    assert ucm_jit.at_point(b) is first and b.point is first
    assert np.allclose(first[0], cmkf_arrays(b, None)[0], rtol=1e-12)
    empty = batch(rng, 0, 3, np.zeros(0, bool))
    z, r = ucm_jit.at_point(empty)
    assert z.shape == (0, 3) and r.shape == (0, 3, 3)
