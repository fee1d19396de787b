"""Unit tests of zenoh_track.tracking.tracker.Tracker (stacked CV / CA tracks, no Zenoh)."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from conftest import make_tracker as make
from reference.record import track

from zenoh_track.estimation import models, ucm
from zenoh_track.estimation import polar as geometry
from zenoh_track.tracking.batches import Instant
from zenoh_track.wire import Measurement


def cart(target, t, pos, sigma=0.0, sensor="s1"):
    sig = sigma if isinstance(sigma, tuple | list) else (sigma,) * len(pos)
    return Measurement(sensor, target, float(t), len(pos), False, tuple(map(float, pos)),
                       tuple(map(float, sig)), (0.0, 0.0, 0.0), None)


def polar(target, t, r, az, el=None, sr=10.0, saz=0.01, sel=0.01, sensor_pos=(0.0, 0.0, 0.0)):
    vals = (r, az) if el is None else (r, az, el)
    sig = (sr, saz) if el is None else (sr, saz, sel)
    return Measurement("radar", target, float(t), len(vals), True, vals, sig,
                       tuple(sensor_pos), None)


def dump(table):
    """Deep copy of everything a rejected input must leave untouched."""
    banks = {d: {k: np.copy(getattr(b, k)) for k in
                 ("x", "p", "t", "t_first", "updates", "nis", "alive")}
             | {"ids": list(b.ids), "free": list(b.free)}
             for d, b in table.store.layouts.items()}
    return banks, {k: (b.dim, row) for k, (b, row) in table.store.where.items()}


def assert_same(before, after):
    banks0, where0 = before
    banks1, where1 = after
    assert where0 == where1
    assert banks0.keys() == banks1.keys()
    for d in banks0:
        for k, v in banks0[d].items():
            if isinstance(v, np.ndarray):
                np.testing.assert_array_equal(banks1[d][k], v, err_msg=k)
            else:
                assert banks1[d][k] == v, k


# ---------------------------------------------------------------- initiation / update
def test_two_exact_points_give_exact_velocity_q0():
    # q = 0, init_speed s = 1000. After point 1 (exact): P_pos = 0, P_vel = s^2 I.
    # Predict dt = 2: P_pos = dt^2 s^2, P_pv = dt s^2. Exact point 2 (R = 0):
    # K_v = dt s^2 / (dt^2 s^2 + 1e-9) = 1/dt (1 - 2.5e-16): v = (z2 - z1)/dt exactly
    # up to rounding; x = z2. (20, -10, 6) / 2 = (10, -5, 3).
    table = make(order=2, q=0.0)
    out, _ = track(table, [cart("a", 0.0, (100.0, 200.0, 300.0))])
    assert out[0].reason is None
    assert table.state("a")["updates"] == 1
    out, _ = track(table, [cart("a", 2.0, (120.0, 190.0, 306.0))])
    assert out[0].reason is None
    st = table.state("a")
    np.testing.assert_allclose(st["vel"], [10.0, -5.0, 3.0], rtol=1e-12)
    np.testing.assert_allclose(st["pos"], [120.0, 190.0, 306.0], rtol=1e-12)
    assert st["updates"] == 2 and st["t"] == 2.0 and st["model"] == "cv"
    assert len(st["x"]) == 6 and len(st["P"]) == 36


def test_two_exact_points_with_process_noise_up_to_prior():
    # q = 1, s = 1000, dt = 2, one axis (continuous white acceleration, density q^2 dt):
    # P_pp = dt^2 s^2 + q^2 dt^4/3 = 4e6 + 16/3, P_vp = dt s^2 + q^2 dt^3/2 = 2e6 + 4,
    # P_vv = s^2 + q^2 dt^2 = 1e6 + 4. K_v = (2e6 + 4) / (4e6 + 16/3) (the 1e-9 floor is
    # below rtol), so v = K_v * dz.
    # Posterior P_vv = P_vv - P_vp^2 / P_pp = 1e6 + 4 - (2e6 + 4)^2 / (4e6 + 16/3).
    table = make(order=2, q=1.0)
    track(table, [cart("a", 0.0, (0.0, 0.0))])
    track(table, [cart("a", 2.0, (20.0, -10.0))])
    st = table.state("a")
    k_v = (2e6 + 4) / (4e6 + 16 / 3)
    np.testing.assert_allclose(st["vel"][:2], [20 * k_v, -10 * k_v], rtol=1e-12)
    assert st["vel"][2] == 0.0 and st["pos"][2] == 0.0  # 2-D track: z = 0 on the wire
    p = np.array(st["P"]).reshape(4, 4)
    pvv = 1e6 + 4 - (2e6 + 4) ** 2 / (4e6 + 16 / 3)
    np.testing.assert_allclose([p[2, 2], p[3, 3]], [pvv, pvv], rtol=1e-6)
    np.testing.assert_allclose(p[:2, :2], np.zeros((2, 2)), atol=1e-6)


def test_initiation_prior_ca():
    # CA: x = [z, 0, 0], P = blockdiag(R, init_speed^2 I, init_accel^2 I).
    table = make(order=3, init_speed=100.0, init_accel=5.0)
    track(table, [cart("a", 1.0, (1.0, 2.0, 3.0), sigma=(1.0, 2.0, 3.0))])
    st = table.state("a")
    np.testing.assert_array_equal(st["x"], [1, 2, 3, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(np.array(st["P"]).reshape(9, 9),
                                  np.diag([1, 4, 9, 1e4, 1e4, 1e4, 25, 25, 25]))
    assert st["model"] == "ca"


def test_polar_initiation_uses_ucm_and_sensor_position():
    # Polar initiation: position = sensor_pos + UCM point, P_pos = UCM covariance at that
    # (sensor-relative) point.
    table = make()
    m = polar("p", 0.0, 5000.0, 0.7, el=0.2, sr=20.0, saz=0.02, sel=0.03,
              sensor_pos=(100.0, -50.0, 10.0))
    track(table, [m])
    rel = geometry.unbiased(np.array([5000.0]), np.array([0.7]), np.array([0.2]),
                           np.array([0.02]), np.array([0.03]))
    cov = geometry.ucm_covariance(rel, np.array([20.0]), np.array([0.02]), np.array([0.03]))
    st = table.state("p")
    np.testing.assert_allclose(st["pos"], rel[0] + [100.0, -50.0, 10.0], rtol=1e-12)
    np.testing.assert_allclose(np.array(st["P"]).reshape(6, 6)[:3, :3], cov[0], rtol=1e-12)


def test_polar_update_evaluates_r_at_prediction():
    # Second polar measurement: R = UCM covariance averaged over the predicted sensor-relative
    # position (ucm.ucm_covariance_expected), and the result equals a hand-assembled
    # predict + Kalman update.
    cfg = dict(order=2, q=2.0)
    table = make(**cfg)
    track(table, [polar("p", 0.0, 4000.0, -2.0, sr=15.0, saz=0.03, sensor_pos=(5.0, 7.0, 0.0))])
    bank, row = table.store.where["p"]
    x0, p0 = bank.x[row].copy(), bank.p[row].copy()
    track(table, [polar("p", 1.5, 4100.0, -1.98, sr=15.0, saz=0.03, sensor_pos=(5.0, 7.0, 0.0))])
    xp, pp = models.predict(x0[None], p0[None], np.array([1.5]), 2, 2, 2.0)
    z = geometry.unbiased(np.array([4100.0]), np.array([-1.98]), None, np.array([0.03]), None)
    z = z + [5.0, 7.0]
    r = ucm.ucm_covariance_expected(xp[:, :2] - [5.0, 7.0], pp[:, :2, :2],
                                        np.array([15.0]), np.array([0.03]), None,
                                        np.array([-1.98]))
    s = pp[0, :2, :2] + r[0]
    k = pp[0, :, :2] @ np.linalg.inv(s)
    x_exp = xp[0] + k @ (z[0] - xp[0, :2])
    np.testing.assert_allclose(bank.x[row], x_exp, rtol=1e-9)
    nu = z[0] - xp[0, :2]
    np.testing.assert_allclose(bank.nis[row], nu @ np.linalg.solve(s, nu), rtol=1e-6)


# ---------------------------------------------------------------- rejections
def test_dimension_mismatch_rejected_and_changes_nothing():
    table = make()
    track(table, [cart("a", 0.0, (1.0, 2.0, 3.0)), cart("b", 0.0, (1.0, 2.0))])
    track(table, [cart("a", 1.0, (2.0, 3.0, 4.0), sigma=1.0)])
    before = dump(table)
    out, _ = track(table, [cart("a", 2.0, (5.0, 5.0), sigma=1.0),
                       polar("b", 2.0, 100.0, 0.1, el=0.1)])
    assert "2-D measurement for a 3-D track" in out[0].reason
    assert "3-D measurement for a 2-D track" in out[1].reason
    assert_same(before, dump(table))


def test_out_of_sequence_rejected_and_changes_nothing():
    table = make()
    track(table, [cart("a", 0.0, (0.0, 0.0, 0.0), sigma=1.0)])
    track(table, [cart("a", 5.0, (5.0, 0.0, 0.0), sigma=1.0)])
    before = dump(table)
    out, _ = track(table, [cart("a", 4.0, (4.0, 0.0, 0.0), sigma=1.0)])
    assert "out of sequence" in out[0].reason and "t=4.000000" in out[0].reason
    assert "t=5.000000" in out[0].reason
    assert_same(before, dump(table))
    # within the 1 us tolerance it counts as simultaneous: from another sensor it is
    # applied, from the same sensor it is a duplicate
    out, _ = track(table, [cart("a", 5.0 - 0.5e-6, (5.0, 0.0, 0.0), sigma=1.0)])
    assert out[0].reason.startswith("duplicate: sensor s1")
    assert_same(before, dump(table))
    out, _ = track(table, [cart("a", 5.0 - 0.5e-6, (5.0, 0.0, 0.0), sigma=1.0, sensor="s2")])
    assert out[0].reason is None
    assert table.state("a")["updates"] == 3


def test_duplicates_in_one_batch_and_after_deletion():
    table = make(delete_after=2.0)
    out, _ = track(table, [cart("a", 0.0, (0.0, 0.0, 0.0), sigma=1.0),
                          cart("a", 0.0, (0.0, 0.0, 0.0), sigma=1.0)])
    assert out[0].reason is None and out[1].reason.startswith("duplicate")
    assert table.state("a")["updates"] == 1
    table.step(Instant(10.0))  # deleted: the id starts afresh
    out, _ = track(table, [cart("a", 0.0, (0.0, 0.0, 0.0), sigma=1.0)])
    assert out[0].reason is None and table.state("a")["updates"] == 1


def test_rejection_in_batch_leaves_other_rows_updated():
    table = make()
    track(table, [cart("a", 0.0, (0.0, 0.0, 0.0), sigma=1.0),
                 cart("b", 0.0, (9.0, 9.0, 9.0), sigma=1.0)])
    track(table, [cart("a", 5.0, (5.0, 0.0, 0.0), sigma=1.0)])
    out, _ = track(table, [cart("a", 1.0, (0.0, 0.0, 0.0)), cart("b", 1.0, (10.0, 9.0, 9.0))])
    assert out[0].reason is not None and out[1].reason is None
    assert table.state("a")["updates"] == 2 and table.state("b")["updates"] == 2


def test_target_measured_twice_in_one_batch():
    # One batch [a@0, b@0, a@1, a@2, b@1] must equal the same measurements applied one
    # at a time: a initiated and updated twice, b initiated and updated once.
    seq = [cart("a", 0.0, (0.0, 0.0, 0.0), sigma=1.0),
           cart("b", 0.0, (50.0, 0.0, 0.0), sigma=2.0),
           cart("a", 1.0, (10.0, 1.0, 0.0), sigma=1.0),
           cart("a", 2.0, (20.0, 2.5, 0.5), sigma=1.0),
           cart("b", 1.0, (49.0, 3.0, 0.0), sigma=2.0)]
    batch = make()
    out, _ = track(batch, seq)
    assert [o.reason for o in out] == [None] * 5
    assert [o.meas for o in out] == seq  # outcomes in input order
    single = make()
    for m in seq:
        track(single, [m])
    for tid, n in (("a", 3), ("b", 2)):
        sb, ss = batch.state(tid), single.state(tid)
        assert sb["updates"] == ss["updates"] == n
        np.testing.assert_allclose(sb["x"], ss["x"], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(sb["P"], ss["P"], rtol=1e-12, atol=1e-12)
        assert sb["t"] == ss["t"]


# ---------------------------------------------------------------- snapshot
@pytest.mark.parametrize("order", [2, 3])
def test_snapshot_equals_full_predict(order):
    q = 1.7
    table = make(order=order, q=q)
    rng = np.random.default_rng(12)
    for k in range(4):
        t = float(k)
        track(table, [cart(f"c3-{i}", t + 0.1 * i, rng.normal(0, 100, 3) + 30 * k, sigma=5.0)
                     for i in range(5)])
        track(table, [cart(f"c2-{i}", t + 0.05 * i, rng.normal(0, 100, 2) + 20 * k,
                          sigma=(3.0, 4.0)) for i in range(3)])
        track(table, [polar("p3", t, 3000.0 + 50 * k, 0.3 + 0.01 * k, el=0.2)])
    for t_snap in (3.0, 3.6, 10.0, 2.5):  # 2.5: before some last updates (negative dt)
        snap = table.snapshot(t_snap)
        assert len(snap.ids) == len(table) == 9
        for i, tid in enumerate(snap.ids):
            bank, row = table.store.where[tid]
            d = bank.dim
            dt = np.array([t_snap - bank.t[row]])
            xp, pp = models.predict(bank.x[row][None], bank.p[row][None], dt, order, d, q)
            pos = np.zeros(3)
            vel = np.zeros(3)
            pos[:d], vel[:d] = xp[0, :d], xp[0, d:2 * d]
            np.testing.assert_allclose(snap.pos[i], pos, rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(snap.vel[i], vel, rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(snap.sigma[i], math.sqrt(np.trace(pp[0, :d, :d])),
                                       rtol=1e-10)
            assert snap.age[i] == pytest.approx(max(t_snap - bank.t[row], 0.0))  # clamped


def test_snapshot_does_not_change_table():
    table = make()
    track(table, [cart("a", 0.0, (0.0, 0.0, 0.0), sigma=1.0)])
    track(table, [cart("a", 1.0, (1.0, 0.0, 0.0), sigma=1.0)])
    before = dump(table)
    table.snapshot(7.0)
    assert_same(before, dump(table))


def test_snapshot_empty():
    snap = make().snapshot(1.0)
    assert snap.ids == [] and snap.pos.shape == (0, 3) and snap.sigma.shape == (0,)


def test_status_tentative_confirmed_coasting():
    # CV: confirmed after 2 updates (order). Interval = (t_last - t_first)/(updates - 1)
    # = 1 s; coasting when age > 2.5 * 1 s.
    table = make(order=2, coast_after=2.5)
    track(table, [cart("a", 0.0, (0.0, 0.0, 0.0), sigma=1.0)])
    assert table.snapshot(100.0).status == ["tentative"]  # one update: no interval yet
    track(table, [cart("a", 1.0, (1.0, 0.0, 0.0), sigma=1.0)])
    assert table.snapshot(3.4).status == ["confirmed"]  # age 2.4 <= 2.5
    assert table.snapshot(3.6).status == ["coasting"]  # age 2.6 > 2.5


def test_status_ca_needs_three_updates():
    # CA (order 3): confirmed only once the acceleration is observable, after 3 updates.
    table = make(order=3)
    for k in range(3):
        track(table, [cart("a", float(k), (k, 0.0, 0.0), sigma=1.0)])
        assert table.snapshot(k + 0.5).status == ["tentative" if k < 2 else "confirmed"]


# ---------------------------------------------------------------- stale / delete
def test_stale_and_delete():
    table = make(delete_after=30.0)
    track(table, [cart("a", 0.0, (0.0, 0.0, 0.0)), cart("b", 10.0, (5.0, 5.0))])
    stale = functools.partial(table.deleter.delete_tracks, table.store)
    assert stale(30.0) == []  # age exactly 30 is not "longer than"
    assert stale(30.5) == ["a"]
    assert sorted(stale(41.0)) == ["a", "b"]
    table.store.remove(["a"])
    assert len(table) == 1 and "a" not in table.store.where
    assert table.snapshot(31.0).ids == ["b"]
    with pytest.raises(KeyError):
        table.state("a")
    # a new track under the same id starts afresh
    # ... and the scan at t = 50 deletes b, 40 s without a measurement (the loop's deleter)
    _, deleted = track(table, [cart("a", 50.0, (7.0, 8.0, 9.0))])
    assert deleted == ["b"] and "b" not in table.store
    st = table.state("a")
    assert st["updates"] == 1 and st["t"] == 50.0 and st["pos"] == [7.0, 8.0, 9.0]
    table.store.remove(["a"])
    assert len(table) == 0 and stale(1e9) == [] and table.snapshot(0.0).ids == []


def test_deleted_row_is_reused_cleanly():
    table = make()
    track(table, [cart("a", 0.0, (1.0, 1.0, 1.0), sigma=1.0)])
    track(table, [cart("a", 1.0, (2.0, 1.0, 1.0), sigma=1.0)])
    table.store.remove(["a"])
    track(table, [cart("z", 5.0, (9.0, 9.0, 9.0), sigma=2.0)])
    st = table.state("z")
    np.testing.assert_array_equal(st["x"], [9, 9, 9, 0, 0, 0])
    assert st["updates"] == 1 and st["nis"] == 0.0
    assert table.snapshot(5.0).status == ["tentative"]


def test_capacity_growth_keeps_states():
    # 40 tracks initiated and updated once (non-trivial x, P), then 100 more in one batch
    # (64 -> 128 -> 256 rows during initiation): the 40 filtered states are unchanged,
    # the new ones hold their measurement, and a further update of all 140 works.
    table = make(q=0.0)
    track(table, [cart(f"t{i}", 0.0, (i, 2.0 * i, -i), sigma=1.0) for i in range(40)])
    track(table, [cart(f"t{i}", 0.5, (i + 0.5, 2.0 * i, -i), sigma=1.0) for i in range(40)])
    saved = {f"t{i}": table.state(f"t{i}") for i in range(40)}
    track(table, [cart(f"t{i}", 0.0, (i, 2.0 * i, -i)) for i in range(40, 140)])
    assert len(table) == 140
    bank = table.store.layouts[3]
    assert len(bank.ids) >= 140
    assert len({row for _, row in table.store.where.values()}) == 140
    for tid, st in saved.items():
        assert table.state(tid) == st
    for i in range(40, 140):
        np.testing.assert_array_equal(table.state(f"t{i}")["x"], [i, 2 * i, -i, 0, 0, 0])
    # one more exact point 1 s later moves each new track by (1, -1, 0.5 i): v = that / 1 s
    out, _ = track(table, [cart(f"t{i}", 1.0, (i + 1.0, 2.0 * i - 1.0, -i + 0.5 * i))
                       for i in range(140)])
    assert all(o.reason is None for o in out)
    for i in range(40, 140):
        st = table.state(f"t{i}")
        np.testing.assert_allclose(st["vel"], [1.0, -1.0, 0.5 * i], rtol=1e-9, atol=1e-9)
        assert st["updates"] == 2
    for i in range(40):
        assert table.state(f"t{i}")["updates"] == 3


# ---------------------------------------------------------------- documented bugs
def test_non_finite_conversion_rejects_only_that_measurement():
    # sigma = 1e200 is accepted by validate (finite, >= 0) but sigma^2 overflows to inf.
    table = make()
    with np.errstate(over="ignore"):
        out, _ = track(table, [cart("good", 0.0, (1.0, 2.0, 3.0), sigma=1.0),
                           cart("huge", 0.0, (1.0, 2.0, 3.0), sigma=1e200)])
    assert out[1].reason is not None and "huge" not in table.store.where
    assert out[0].reason is None and "good" in table.store.where


def test_singular_innovation_does_not_break_the_batch():
    table = make()
    track(table, [polar("bad", 0.0, 1.0, 1.0, sr=1e6, saz=0.0),
                 cart("ok", 0.0, (0.0, 0.0), sigma=1.0)])
    out, _ = track(table, [polar("bad", 0.0, 1.0, 1.0, sr=1e6, saz=0.0),
                       cart("ok", 1.0, (1.0, 0.0), sigma=1.0)])
    assert out[1].reason is None
    assert table.state("ok")["updates"] == 2
