"""The filter core on columns: MeasurementBatch, the fused filters.cmkf_step against the
parts called one by one, chunking, and the batch-last kernels against row-major
reference formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from zenoh_track.estimation import filters, kalman, linalg, models, polar, scratch
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.estimation.ucm import cmkf_arrays
from zenoh_track.wire import Measurement


def polar3(target: str, t: float, r: float, az: float, el: float,
           origin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Measurement:
    return Measurement("s", target, t, 3, True, (r, az, el), (15.0, 0.004, 0.006), origin, None)


def cart3(target: str, t: float, pos: tuple[float, float, float]) -> Measurement:
    return Measurement("s", target, t, 3, False, pos, (3.0, 4.0, 5.0), (0.0, 0.0, 0.0), None)


def test_batch_columns_from_records():
    meas = [polar3("a", 1.0, 5000.0, 0.3, 0.1, (1.0, 2.0, 3.0)),
            cart3("b", 2.0, (10.0, 20.0, 30.0))]
    b = MeasurementBatch.of(meas, 3)
    assert len(b) == 2 and b.dim == 3
    np.testing.assert_array_equal(b.t, [1.0, 2.0])
    np.testing.assert_array_equal(b.polar, [True, False])
    np.testing.assert_array_equal(b.values, [[5000.0, 0.3, 0.1], [10.0, 20.0, 30.0]])
    np.testing.assert_array_equal(b.sigmas, [[15.0, 0.004, 0.006], [3.0, 4.0, 5.0]])
    np.testing.assert_array_equal(b.origin, [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    empty = MeasurementBatch.of([], 3)
    assert len(empty) == 0 and empty.values.shape == (0, 3)


def test_batch_rejects_mixed_dimensions():
    two = Measurement("s", "c", 0.0, 2, False, (1.0, 2.0), (1.0, 1.0), (0.0, 0.0, 0.0), None)
    with pytest.raises(ValueError, match="mixed dimensions"):
        MeasurementBatch.of([cart3("a", 0.0, (1.0, 2.0, 3.0)), two], 3)


def scene(n: int, order: int, seed: int = 1):
    """Priors (N, n) / (N, n, n) of targets 2-60 km from sensors, and one measurement
    each (every fifth Cartesian), with dt between 0.5 and 2 s."""
    rng = np.random.default_rng(seed)
    dim = 3
    ns = order * dim
    pos = rng.uniform(-40e3, 40e3, (n, dim))
    pos[:, 2] = rng.uniform(200.0, 12e3, n)
    pos[:3, :2] = rng.uniform(-50.0, 50.0, (3, 2))  # three nearly overhead
    x = np.zeros((n, ns))
    x[:, :dim] = pos
    x[:, dim:2 * dim] = rng.normal(0.0, 150.0, (n, dim))
    a = rng.normal(size=(n, ns, ns)) * np.repeat([30.0, 8.0, 1.0][:order], dim)[:, None]
    p = a @ a.transpose(0, 2, 1) + 1.0 * np.eye(ns)
    dt = rng.uniform(0.5, 2.0, n)
    meas = []
    for i in range(n):
        truth = pos[i] + x[i, dim:2 * dim] * dt[i] + rng.normal(0.0, 20.0, dim)
        if i % 5 == 4:
            meas.append(cart3(f"t{i}", dt[i], tuple(truth.tolist())))
        else:
            origin = tuple(rng.uniform(-500.0, 500.0, 3).tolist())
            r, az, el = polar.cartesian_to_polar((truth - origin)[None])
            meas.append(polar3(f"t{i}", dt[i], float(r[0]), float(az[0]), float(el[0]),
                               origin))
    return x, p, dt, MeasurementBatch.of(meas, dim)


@pytest.mark.parametrize("order", [2, 3])
def test_cmkf_step_equals_the_parts(order):
    x, p, dt, batch = scene(40, order)
    q = 0.7
    xn, pn, nis, ok = filters.cmkf_step(x, p, dt, order, 3, q, batch)
    xp, pp = models.predict(x, p, dt, order, 3, q)
    z, r = cmkf_arrays(batch, xp[:, :3], pp[:, :3, :3])
    xr, pr, nisr, okr = kalman.update(xp, pp, z, r)
    assert ok.all() and okr.all()
    np.testing.assert_allclose(xn, xr, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(pn, pr, rtol=1e-11, atol=1e-9)
    np.testing.assert_allclose(nis, nisr, rtol=1e-9)
    assert np.array_equal(pn, pn.transpose(0, 2, 1))


def test_chunks_give_the_same_rows(monkeypatch):
    x, p, dt, batch = scene(23, 2)
    whole = filters.cmkf_step(x, p, dt, 2, 3, 1.0, batch)
    monkeypatch.setattr(scratch, "CHUNK", 5)
    assert scratch.chunks(23) == [(0, 4), (4, 9), (9, 13), (13, 18), (18, 23)]
    parts = filters.cmkf_step(x, p, dt, 2, 3, 1.0, batch)
    for a, b in zip(whole, parts, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-12)


def test_joseph_update_matches_row_major_reference():
    # P+ = (I - KH) P (I - KH)' + K R K' with K = P H' S^-1 (S with the 1e-9 floor)
    x, p, dt, batch = scene(12, 2, seed=4)
    z, r = cmkf_arrays(batch, x[:, :3], p[:, :3, :3])
    xn, pn, nis, _ = kalman.update(x, p, z, r)
    h = np.hstack([np.eye(3), np.zeros((3, 3))])
    for i in range(len(x)):
        s = h @ p[i] @ h.T + r[i] + kalman.S_FLOOR * np.eye(3)
        k = p[i] @ h.T @ np.linalg.inv(s)
        ikh = np.eye(6) - k @ h
        nu = z[i] - h @ x[i]
        np.testing.assert_allclose(xn[i], x[i] + k @ nu, rtol=1e-12)
        np.testing.assert_allclose(pn[i], ikh @ p[i] @ ikh.T + k @ r[i] @ k.T, rtol=1e-10,
                                   atol=1e-9 * np.abs(pn[i]).max())
        np.testing.assert_allclose(nis[i], nu @ np.linalg.solve(s, nu), rtol=1e-10)


def test_expected_ucm_eigen_points_match_numpy_eigh():
    # The closed-form eigen pairs behind the cubature points equal np.linalg.eigh's (up to
    # order and sign), also for nearly repeated eigenvalues.
    rng = np.random.default_rng(2)
    a = rng.normal(size=(200, 3, 3))
    cov = a @ a.transpose(0, 2, 1)
    cov[:50] = np.diag([400.0, 400.0 * (1 + 1e-9), 25.0])  # two almost equal
    vals, vecs = linalg.eigh(np.ascontiguousarray(cov.transpose(1, 2, 0)), 3)
    got = np.sort(np.array(vals).T, axis=1)
    want = np.linalg.eigvalsh(cov)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * want.max())
    for k in range(3):  # each vector: cov v = lambda v, |v| = 1
        v = np.asarray(vecs[k]).T
        np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, rtol=1e-12)
        resid = np.einsum("nij,nj->ni", cov, v) - np.asarray(vals[k])[:, None] * v
        assert np.abs(resid).max() < 1e-9 * want.max()


def test_work_arrays_are_kept():
    a = scratch.buffer("test.a", (2, 3), 50)
    b = scratch.buffer("test.a", (2, 3), 50)
    c = scratch.buffer("test.a", (2, 3), 20)
    assert a is b and c.base is a.base and c.flags.c_contiguous
    assert math.prod(c.shape) == 120
