"""The per-scan shortcuts give the same bits as the plain steps they replace:
the Kalman update's fused contractions, the all-Cartesian conversion, the gate's
prediction of the position rows, the lazily cut gatings, the conversion at the point
taken with a batch's rows, the columns of a batch and the track ids of a scan."""

from __future__ import annotations

import numpy as np
import pytest
from reference.record import Outcome, scan_step

from zenoh_track.estimation import kalman, models
from zenoh_track.estimation.linalg import ldl_inverse
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.estimation.ucm import at_point, cmkf_arrays, cmkf_soa
from zenoh_track.tracking import gating
from zenoh_track.tracking import plot_association as association
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import Measurement


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the last bit (the sign of a zero and the payload of a NaN included)."""
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def spd(rng: np.random.Generator, n_rows: int, n: int, scale: float) -> np.ndarray:
    a = rng.normal(size=(n_rows, n, n)) * scale
    return a @ a.transpose(0, 2, 1) + np.eye(n)


def update_in_steps(x, p, z, r, p_out, nis, det):
    """`kalman.update_soa` as it was before the fusion: K' and S^-1 nu as two
    contractions, the Joseph form row by row (np.einsum itself, batch axis last)."""
    n, k = x.shape
    m = z.shape[0]
    nu = z - x[:m]
    s0 = p[:m, :m] + r
    sinv = np.empty((m, m, k))
    ldl_inverse(s0, sinv, det, kalman.S_FLOOR)
    kt = np.einsum("abn,bin->ain", sinv, p[:m])
    sn = np.einsum("abn,bn->an", sinv, nu)
    nis[:] = np.einsum("an,an->n", nu, sn)
    x += np.einsum("ain,an->in", kt, nu)
    et = p[:m] - np.einsum("ban,bin->ain", s0, kt)
    up, lk = np.concatenate([p[:m], kt]), np.concatenate([kt, et])
    for i in range(n):
        p_out[i, i:] = p[i, i:] - np.einsum("an,ajn->jn", lk[:, i], up[:, i:])
    for i in range(n - 1):
        p_out[i + 1:, i] = p_out[i, i + 1:]


@pytest.mark.parametrize(("m", "order", "rows"), [(2, 2, 37), (3, 2, 5), (2, 3, 64),
                                                  (3, 3, 2)])
def test_update_contractions_fused_give_the_same_bits(m, order, rows):
    rng = np.random.default_rng(m * 10 + order)
    n = m * order
    x = rng.normal(size=(n, rows)) * 1e3
    p = np.ascontiguousarray(spd(rng, rows, n, 30.0).transpose(1, 2, 0))
    p[:m, m:, :3] = p[m:, :m, :3] = 0.0  # exact zeros, as in a track after initiation
    z = rng.normal(size=(m, rows)) * 1e3
    r = np.ascontiguousarray(spd(rng, rows, m, 10.0).transpose(1, 2, 0))
    got = [x.copy(), np.empty((n, n, rows)), np.empty(rows), np.empty(rows)]
    want = [x.copy(), np.empty((n, n, rows)), np.empty(rows), np.empty(rows)]
    kalman.update_soa(got[0], p, z, r, *got[1:])
    update_in_steps(want[0], p, z, r, *want[1:])
    for a, b in zip(got, want, strict=True):
        assert same_bits(a, b)


@pytest.mark.parametrize(("order", "dim", "rows"), [(2, 2, 17), (2, 3, 1), (3, 2, 2),
                                                    (3, 3, 40)])
def test_prediction_block_by_block_gives_the_same_bits(order, dim, rows):
    rng = np.random.default_rng(order * 10 + dim)
    n = order * dim
    x = rng.normal(size=(rows, n)) * 1e3
    p = spd(rng, rows, n, 20.0)
    p[:, dim:, :dim] += 1e-9 * rng.normal(size=(rows, n - dim, dim))  # not quite symmetric
    dt = rng.uniform(-1.0, 3.0, rows)
    q = rng.uniform(0.5, 2.0, rows)
    xs, ps = x.T.copy(), p.transpose(1, 2, 0).copy()  # copies (one row: a view is contiguous)
    models.predict_soa(xs, ps, dt, order, dim, q)
    xb, out = x.T.copy(), np.empty((n, n, rows))
    blocks = models.to_blocks(p, order, dim, np.empty((order, order, dim, dim, rows)))
    models.predict_blocks(xb, blocks, dt, order, dim, q, out)
    assert same_bits(xb, xs) and same_bits(out, ps)


def batch_of(values: np.ndarray, sigmas: np.ndarray, polar: np.ndarray) -> MeasurementBatch:
    k = len(values)
    return MeasurementBatch(np.zeros(k), polar, np.asfortranarray(values),
                            np.asfortranarray(sigmas), np.zeros((k, 3)))


def test_all_cartesian_conversion_is_the_masked_one():
    rng = np.random.default_rng(1)
    k = 9
    values, sigmas = rng.normal(size=(k, 2)) * 1e3, rng.uniform(5.0, 50.0, (k, 2))
    pos = np.ascontiguousarray(values.T) + 10.0
    cov = np.ascontiguousarray(spd(rng, k, 2, 20.0).transpose(1, 2, 0))
    polar = np.zeros(k, dtype=bool)
    z, r = np.empty((2, k)), np.empty((2, 2, k))
    cmkf_soa(batch_of(values, sigmas, polar), pos, cov, z, r)  # the whole-batch path
    mixed_values = values.copy()
    mixed_values[0] = (5000.0, 0.3)  # one polar row: the masked path for the others
    polar[0] = True
    zm, rm = np.empty((2, k)), np.empty((2, 2, k))
    cmkf_soa(batch_of(mixed_values, sigmas, polar), pos, cov, zm, rm)
    assert same_bits(z[:, 1:], zm[:, 1:]) and same_bits(r[:, :, 1:], rm[:, :, 1:])
    z0, r0 = cmkf_arrays(batch_of(values, sigmas, np.zeros(k, dtype=bool)), None)
    assert same_bits(z, z0.T) and same_bits(r, r0.transpose(1, 2, 0))  # = at the point


def test_gate_prediction_is_the_filter_prediction():
    """The gate's predicted position equals the filter's to the bit (the same sums), its
    rows of the covariance to rounding (Q is summed in another order), for CV and CA:
    the strided diagonals carry Q as a loop over the entries did."""
    rng = np.random.default_rng(2)
    rows, dim = 30, 2
    dt = rng.uniform(-0.5, 3.0, rows)
    for order in (2, 3):
        n = dim * order
        x, p = rng.normal(size=(rows, n)) * 1e3, spd(rng, rows, n, 20.0)
        mean, cross = models.predict_position(x, p, dt, order, dim, 1.3)
        xp, pp = models.predict(x, p, dt, order, dim, 1.3)
        assert same_bits(mean, xp[:, :dim])
        np.testing.assert_allclose(cross, pp[:, :dim], rtol=1e-12, atol=1e-9)


def test_cut_gatings_read_their_source_on_first_use():
    rng = np.random.default_rng(3)
    tracker = Tracker.from_config(TrackerConfig(associator="gnn"))
    pts = rng.uniform(0, 3000, (12, 2))
    for k in range(2):
        scan_step(tracker, [Outcome(det(float(k), q))
                            for q in pts + rng.normal(0, 20, pts.shape)], float(k))
    arrays = tracker.store.layout(2)
    rows = arrays.rows()
    dets = np.vstack([pts + rng.normal(0, 30, pts.shape), rng.uniform(0, 3000, (20, 2))])
    z, r = gating.convert(MeasurementBatch.of([det(2.0, q) for q in dets], 2))
    g = gating.gate(arrays, rows, z, r, 2.0, 1.0, gating.gate_threshold(0.999, 2))
    score = association.scores(g, 0.9, 1e-8)[0]
    tracks = np.arange(len(rows)) % 3 != 0
    dets_kept = np.flatnonzero(np.arange(len(dets)) % 4 != 1)
    cut = gating.restrict(g, tracks, dets_kept)
    keep = tracks[g.ti] & np.isin(g.dj, dets_kept)
    assert len(cut.ti) == keep.sum() > 5
    assert same_bits(cut.rows, g.rows[tracks]) and same_bits(cut.z, g.z[dets_kept])
    for name in ("d2", "loglik", "nu"):
        assert same_bits(getattr(cut, name), getattr(g, name)[keep])
    assert same_bits(cut.mean, g.mean[tracks]) and same_bits(cut.cross, g.cross[tracks])
    assert same_bits(cut.r, g.r[dets_kept])
    assert same_bits(association.scores(cut, 0.9, 1e-8)[0], score[keep])  # taken, not redone
    new_ti = np.cumsum(tracks) - 1
    new_dj = np.searchsorted(dets_kept, g.dj[keep])
    assert same_bits(cut.ti, new_ti[g.ti[keep]]) and same_bits(cut.dj, new_dj)


def det(t: float, pos) -> Measurement:
    return Measurement("r1", "", t, 2, False, (float(pos[0]), float(pos[1])), (25.0, 25.0),
                       (0.0, 0.0, 0.0), None)


def test_taken_batches_take_the_conversion_at_the_point_when_asked():
    rng = np.random.default_rng(4)
    meas = [Measurement("r1", "", 1.0, 3, True, (rng.uniform(1e3, 5e4), rng.uniform(-3, 3),
                                                 rng.uniform(0, 1)), (15.0, 0.004, 0.006),
                        (1.0, 2.0, 3.0), None) for _ in range(30)]
    batch = MeasurementBatch.of(meas, 3)
    z, r = at_point(batch)
    index = [7, 3, 29, 0, 11]
    taken = batch.take(index)
    assert taken.point is None  # nothing taken yet: a filter update never asks
    zt, rt = at_point(taken)
    assert same_bits(zt, z[index]) and same_bits(rt, r[index])
    fresh = MeasurementBatch.of([meas[i] for i in index], 3)
    zf, rf = at_point(fresh)
    assert same_bits(zt, zf) and same_bits(rt, rf)
    part = batch.take(index).rows(1, 4)
    assert same_bits(at_point(part)[0], z[index[1:4]])
    assert taken.values.flags.f_contiguous and same_bits(taken.values, fresh.values)


def test_batch_columns_check_every_record():
    ok = Measurement("s", "", 0.0, 2, False, (1.0, 2.0), (3.0, 4.0), (0.0, 0.0, 0.0), None)
    bad = Measurement("s", "", 0.0, 2, False, (1.0, 2.0), (3.0,), (0.0, 0.0, 0.0), None)
    with pytest.raises(ValueError, match="mixed dimensions"):
        MeasurementBatch.of([ok, bad], 2)
    b = MeasurementBatch.of([ok, ok], 2)
    assert b.values.flags.f_contiguous and b.sigmas.flags.f_contiguous
    assert same_bits(b.sigmas, np.array([[3.0, 4.0], [3.0, 4.0]]))


def test_track_ids_count_per_sensor():
    numbers = Tracker.from_config().numbers
    assert numbers.new("a", 3) == ["a-1", "a-2", "a-3"]
    assert numbers.new("b", 1) == ["b-1"] and numbers.new("a", 1) == ["a-4"]
    assert numbers.new("a", 0) == [] and numbers.new("a", 1) == ["a-5"]
