"""zenoh_track.clients.feeds.plotgen: unlabelled-scan scenarios are deterministic, have the shapes,
detection probability, clutter rate and noise asked for, their polar detections agree with the
truth, and their payloads read back through `zenoh_track.wire.parse_plots` unchanged."""

from __future__ import annotations

import math

import numpy as np
import pytest
from reference.record import track_scan

from zenoh_track.clients.feeds import plotgen
from zenoh_track.wire import parse_plots

NOISE = (1.0, 1.0, 1.0, 1.0)  # parse_plots' fallback noise: the payloads must override it


def same(a: list[plotgen.Scan], b: list[plotgen.Scan]) -> bool:
    return len(a) == len(b) and all(
        x.t == y.t and x.sensor == y.sensor and x.sensor_pos == y.sensor_pos
        and np.array_equal(x.dets, y.dets) and x.truth.keys() == y.truth.keys()
        and all(np.array_equal(x.truth[k][0], y.truth[k][0]) for k in x.truth)
        for x, y in zip(a, b, strict=True))


def test_deterministic_from_the_seed():
    for make in (plotgen.crossing, plotgen.multisensor, plotgen.swarm_plots):
        one = make(seed=3, scans=5)
        assert same(list(one), list(one))  # iterating again gives the same scans
        assert same(list(one), list(make(seed=3, scans=5)))
        assert not same(list(one), list(make(seed=4, scans=5)))


def test_crossing_shapes_geometry_and_region():
    sc = plotgen.crossing(targets=20, scans=100, seed=1)
    scans = list(sc)
    assert [s.t for s in scans] == [float(k) for k in range(100)]
    for s in scans:
        assert s.dets.ndim == 2 and s.dets.shape[1] == 2 and s.sensor == "radar1"
        assert len(s.truth) == 20
        pos, vel = s.truth["t0"]
        assert pos.shape == vel.shape == (2,)
        assert (np.abs(s.dets) <= sc.half_width + 5 * sc.sigma).all()
    # each line passes within 200 m of the origin within a scan of the middle scan
    pos = np.array([[s.truth[k][0] for k in sorted(s.truth)] for s in scans])  # (T, N, 2)
    dist = np.linalg.norm(pos, axis=2)
    speed = np.linalg.norm(scans[0].truth["t0"][1])
    assert 100.0 <= speed <= 250.0
    assert (dist.min(0) <= 200.0 + 125.0).all()  # the closest scan is within half a step
    assert (np.abs(dist.argmin(0) - 50) <= 2).all()
    assert (np.abs(pos) <= sc.half_width).all()  # the region holds every trajectory
    assert sc.clutter_density == pytest.approx(20.0 / sc.area)
    assert sc.area == (2 * sc.half_width) ** 2
    with pytest.raises(ValueError, match="does not hold"):
        plotgen.crossing(half_width=5000.0)


def test_detection_probability_clutter_rate_and_noise():
    """50 targets x 200 scans = 10,000 chances (pd 0.8: std 0.004; tolerance 0.02, 5 std);
    Poisson clutter of mean 30 over 200 scans (std of the mean 0.39; tolerance 2.0); the
    noise std within 5 % (10,000 samples per axis: std of the estimate 0.7 %)."""
    sc = plotgen.crossing(targets=50, pd=0.8, clutter=30.0, sigma=40.0, scans=200, seed=2)
    hits, false, err = 0, [], []
    for s, origin in sc.labelled():
        real = origin >= 0
        hits += real.sum()
        false.append((~real).sum())
        assert len(set(origin[real].tolist())) == real.sum()  # a target once per scan
        truth = np.array([s.truth[f"t{i}"][0] for i in origin[real]]).reshape(-1, 2)
        err.append(s.dets[real] - truth)
        clutter = s.dets[~real]
        assert (np.abs(clutter) <= sc.half_width).all()
    assert hits / (50 * 200) == pytest.approx(0.8, abs=0.02)
    assert np.mean(false) == pytest.approx(30.0, abs=2.0)
    err = np.vstack(err)
    assert np.abs(err.mean(0)).max() < 2.0  # unbiased: 5 std of the mean (0.4 m)
    np.testing.assert_allclose(err.std(0), 40.0, rtol=0.05)


def test_multisensor_phases_and_polar_detections_match_the_truth():
    sc = plotgen.multisensor(targets=20, radars=3, sr=20.0, saz=0.002, scans=40, seed=5)
    scans = list(sc.labelled())
    times = [s.t for s, _ in scans]
    assert times == sorted(times) and len(scans) == 120
    radars = {r.name: r for r in sc.radars}
    assert len({r.pos for r in sc.radars}) == 3 and all(r.polar for r in sc.radars)
    dr, daz, cart = [], [], []
    for s, origin in scans:
        radar = radars[s.sensor]
        assert s.sensor_pos == radar.pos
        k = (s.t - radar.phase) / sc.dt  # radar k scans at its phase + n dt
        assert abs(k - round(k)) < 1e-9 and radar.phase < sc.dt
        real = origin >= 0
        truth = np.array([s.truth[f"t{i}"][0] for i in origin[real]]).reshape(-1, 2)
        r, az = plotgen.to_polar(truth, radar.pos)
        dr.append(s.dets[real, 0] - r)
        daz.append(np.angle(np.exp(1j * (s.dets[real, 1] - az))))
        # the Cartesian point of the detection: x = r sin az, y = r cos az from the radar
        xy = plotgen.to_cartesian(s.dets[real], radar.pos)
        cart.append(np.linalg.norm(xy - truth, axis=1) / np.maximum(r * 0.002, 20.0))
        back = plotgen.to_polar(plotgen.to_cartesian(s.dets, radar.pos), radar.pos)
        np.testing.assert_allclose(back[0], s.dets[:, 0], rtol=1e-9)
    dr, daz = np.concatenate(dr), np.concatenate(daz)
    assert len(dr) > 1500
    np.testing.assert_allclose([dr.std(), daz.std()], [20.0, 0.002], rtol=0.08)
    assert abs(dr.mean()) < 2.0 and abs(daz.mean()) < 2e-4
    assert np.concatenate(cart).max() < 7.0  # within 7 sigma in every case
    # a radar due North of a target sees it at az = pi (South of the radar is az +-pi)
    r, az = plotgen.to_polar(np.array([[0.0, 0.0]]), (0.0, 1000.0, 0.0))
    assert r[0] == 1000.0 and abs(abs(az[0]) - math.pi) < 1e-12
    r, az = plotgen.to_polar(np.array([[1000.0, 0.0]]), (0.0, 0.0, 0.0))
    assert az[0] == pytest.approx(math.pi / 2)  # East: 90 degrees clockwise from North
    with pytest.raises(ValueError):
        plotgen.multisensor(radars=4)


def test_multisensor_scans_through_the_service_find_every_target():
    """The service's own conversion agrees with plotgen's, and our tracker fed the three
    radars' payloads (parse_plots -> Tracker.track_scan) holds a track on every target."""
    from zenoh_track.estimation.polar import polar_to_cartesian
    from zenoh_track.tracking.plot_association import SensorModels
    from zenoh_track.tracking.tracker import Tracker, TrackerConfig

    sc = plotgen.multisensor(targets=10, radars=3, scans=20, clutter=10.0, seed=8)
    tracker = Tracker.from_config(TrackerConfig(sensors=SensorModels(
        pd=sc.pd, clutter_density=sc.clutter_density)))
    for s in sc:
        mine = plotgen.to_cartesian(s.dets, s.sensor_pos)
        theirs = polar_to_cartesian(s.dets[:, 0], s.dets[:, 1], None) + s.sensor_pos[:2]
        np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-6)
        track_scan(tracker, parse_plots(s.sensor, sc.payload(s, columnar=True), NOISE))
    snap = tracker.snapshot(s.t)
    est = np.array([p[:2] for p, st in zip(snap.pos, snap.status, strict=True)
                    if st != "tentative"])
    truth = np.array([p for p, _ in s.truth.values()])
    dist = np.linalg.norm(truth[:, None] - est[None], axis=2)
    assert (dist.min(1) < 150.0).all()  # every target has an established track near it


def test_swarm_shapes():
    sc = plotgen.swarm_plots(targets=2000, clutter=2000.0, scans=3, seed=1)
    scans = list(sc)
    assert len(scans) == 3 and all(len(s.truth) == 2000 for s in scans)
    assert all(3000 < len(s.dets) < 4200 for s in scans)  # 1,800 + 2,000 expected
    pos = np.array([p for p, _ in scans[-1].truth.values()])
    assert (np.abs(pos) <= sc.half_width).all()


@pytest.mark.parametrize("columnar", [False, True])
@pytest.mark.parametrize("kind", ["cartesian", "polar"])
def test_payloads_read_back_the_same_detections(kind, columnar):
    sc = (plotgen.crossing(scans=3, seed=1) if kind == "cartesian" else
          plotgen.multisensor(scans=2, seed=1))
    for s in sc:
        got = parse_plots(s.sensor, sc.payload(s, columnar), NOISE)
        assert got.rejected == () and got.t == s.t and got.sensor_pos == s.sensor_pos
        assert len(got.detections) == len(s.dets) > 0
        values = np.array([m.values for m in got.detections])
        assert np.array_equal(values, s.dets)  # float64 bits: the same numbers
        for m in got.detections:
            assert m.dim == 2 and m.target == "" and m.polar == (kind == "polar")
            assert m.sigmas == ((sc.sigma, sc.sigma) if kind == "cartesian"
                                else (sc.sr, sc.saz))
    empty = plotgen.Scan(1.0, "radar1", (0.0, 0.0, 0.0), np.zeros((0, 2)), {})
    for kw in ({"sigma": 25.0}, {"sr": 25.0, "saz": 0.002}):
        got = parse_plots("radar1", plotgen.payload(empty, columnar, **kw), NOISE)
        assert got.detections == () and got.rejected == ()
    with pytest.raises(ValueError):
        plotgen.payload(empty, columnar, sr=25.0)
