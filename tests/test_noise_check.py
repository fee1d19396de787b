"""Each sensor's stated noise checked against its measurements (`tracking.noise_check`):
the statistic on columns, then through the real service on loopback (lockstep): a sensor
that states sigma 0 but jitters by 20 m is reported in `status` and on `errors/<sensor>`
within 30 s of its first measurement, a sensor stating its noise right is not."""

from __future__ import annotations

import numpy as np
import pytest
import zenoh
from conftest import Collector, make_tracker

from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.tracking.batches import Labelled
from zenoh_track.tracking.noise_check import NoiseCheck
from zenoh_track.wire import MSGPACK_ENCODING, Measurement, pack, unpack


def path(n: int, seed: int = 0, turn: float = 0.02) -> np.ndarray:
    """A smooth 3-D path, one position a second (n, 3): 200 m/s in a slow turn, climbing."""
    t = np.arange(n, dtype=float)
    return np.column_stack([5e3 * np.sin(turn * t) / (turn * 25), 5e3 * (1 - np.cos(turn * t))
                            / (turn * 25), 3e3 + 5.0 * t])


def feed(tracker, sensor: str, target: str, pos: np.ndarray, sigma: float) -> None:
    for k, p in enumerate(pos):
        tracker.step(Labelled.of([Measurement(sensor, target, float(k), 3, False, tuple(p.tolist()),
                                   (sigma,) * 3, (0.0, 0.0, 0.0), None)]))


def test_jitter_stated_exact_is_reported_and_used():
    rng = np.random.default_rng(1)
    truth = path(40)
    tr = make_tracker(order=3, q=0.5)
    feed(tr, "sim", "a", np.round(truth + 20.0 * rng.standard_normal(truth.shape)), 0.0)
    feed(tr, "exact", "b", truth + [1e3, 0, 0], 0.0)
    status = tr.noise.status()
    assert set(status) == {"sim"}
    rep = status["sim"]
    assert rep["direction"] == "too small" and rep["stated"] == 0.0
    assert 14.0 < rep["measured"] < 26.0  # 20 m, estimated from 36 x 3 residuals
    assert rep["count"] >= 30
    # used meanwhile: the measured noise in the update
    batch = MeasurementBatch.of([Measurement("sim", "a", 40.0, 3, False, (0.0, 0.0, 0.0),
                                             (0.0,) * 3, (0.0, 0.0, 0.0), None)], 3)
    ids = tr.store.layout(3).ids
    row, dt, n = np.array([0]), np.array([1.0]), np.array([40])
    used, grow, dp = tr.noise.adjust("sim", batch, row, dt, 3, ids, n)
    np.testing.assert_allclose(used.sigmas, rep["measured"])
    assert len(grow) == 0  # the track took the measured noise in once already
    assert tr.noise.adjust("exact", batch, row + 1, dt, 3, ids, n)[0] is batch


def test_pessimistic_sensor_is_reported_but_not_used():
    rng = np.random.default_rng(2)
    truth = path(40, turn=1e-9)  # straight: the CV filter's model
    tr = make_tracker(order=2)
    feed(tr, "coarse", "a", truth + 1.0 * rng.standard_normal(truth.shape), 100.0)
    rep = tr.noise.status()["coarse"]
    assert rep["direction"] == "too large" and rep["measured"] < 3.0 and rep["nis"] < 0.3
    assert tr.noise.due(0.0) == []  # in status only
    batch = MeasurementBatch.of([Measurement("coarse", "a", 40.0, 3, False, (0.0,) * 3,
                                             (100.0,) * 3, (0.0, 0.0, 0.0), None)], 3)
    ids = tr.store.layout(3).ids
    row, dt, n = np.array([0]), np.array([1.0]), np.array([40])
    assert tr.noise.adjust("coarse", batch, row, dt, 2, ids, n)[0] is batch


def test_reports_are_rate_limited():
    check = NoiseCheck(min_count=3, every=10.0)
    rng = np.random.default_rng(3)
    truth = path(12)
    for k, p in enumerate(truth + 20.0 * rng.standard_normal(truth.shape)):
        batch = MeasurementBatch.of([Measurement("s", "a", float(k), 3, False, tuple(p),
                                                 (0.0,) * 3, (0.0,) * 3, None)], 3)
        check.observe("s", ["a"], np.array([0]), batch, np.array([1e4]), np.array([True]))
    assert [r.sensor for r in check.due(100.0)] == ["s"]
    assert check.due(105.0) == []
    assert [r.sensor for r in check.due(110.0)] == ["s"]


def test_a_reused_row_starts_its_history_afresh():
    check = NoiseCheck(min_count=1)
    truth = path(8)
    for k, p in enumerate(truth):
        name = "a" if k < 4 else "b"  # row 0 is track a, then (deleted) track b
        p = p + (500.0 if name == "b" else 0.0)
        batch = MeasurementBatch.of([Measurement("s", name, float(k), 3, False, tuple(p),
                                                 (0.0,) * 3, (0.0,) * 3, None)], 3)
        check.observe("s", [name], np.array([0]), batch, np.array([3.0]), np.array([True]))
    assert check.status() == {}  # a's last three and b's first do not make a residual


@pytest.mark.slow
def test_service_reports_a_jittering_sensor_within_30_s(service_factory):
    svc, s = service_factory("--clock", "lockstep")
    errors = Collector(s, "track/errors/*")
    rng = np.random.default_rng(4)
    truth = path(30)
    noisy = np.round(truth + 20.0 * rng.standard_normal(truth.shape))
    enc, block = zenoh.Encoding(MSGPACK_ENCODING), zenoh.CongestionControl.BLOCK
    for k in range(30):  # t = 0 .. 29 s: the first 30 s of both sensors
        s.put(svc.keys.meas("sim", "a"), pack({"t": float(k), "pos": noisy[k].tolist(),
                                               "sigma": 0.0}), encoding=enc,
              congestion_control=block)
        s.put(svc.keys.meas("exact", "b"), pack({"t": float(k), "pos": (truth[k] + 1e3).tolist(),
                                                 "sigma": 0.0}), encoding=enc,
              congestion_control=block)
    s.put(svc.keys.clock, pack({"t": 30.0}), encoding=enc, congestion_control=block)
    assert errors.wait_for(lambda ss: any(b and b.get("code") == "noise" for _, _, b in ss))
    key, _, body = next(x for x in errors.samples if x[2] and x[2].get("code") == "noise")
    assert key == "track/errors/sim"
    assert body["stated"] == 0.0 and 14.0 < body["measured"] < 26.0
    assert body["direction"] == "too small" and "stated sigma 0 m" in body["reason"]
    status = unpack(next(iter(s.get(svc.keys.status, timeout=10))).ok.payload.to_bytes())
    assert set(status["sensor_noise"]) == {"sim"}
    assert status["meas_rejected"] == 0 and status["meas_accepted"] == 60
    track = unpack(next(iter(s.get(svc.keys.tracks("a"), timeout=10))).ok.payload.to_bytes())
    assert np.linalg.norm(np.array(track["pos"]) - truth[29]) < 60.0  # stable, smoothed
