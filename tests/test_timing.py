"""Time noise in the measurement model (`estimation.timing`, docs/timing.md): the term
sigma_t^2 (v v' + P_vv) against its plain row-by-row form, in the filters' update; the
`sigma_t` field on the wire (a measurement, a batched scan); the noise check telling time
noise from position noise on positions whose time stamps jitter (`clients.feeds.stamped`)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
import zenoh
from conftest import Collector

from zenoh_track import defaults
from zenoh_track.clients.evaluation import heldout as held
from zenoh_track.clients.feeds import stamped
from zenoh_track.estimation import kalman, models, timing
from zenoh_track.estimation.filters import SingleModelFilter
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.estimation.ucm import CMKFConversion
from zenoh_track.tracking.batches import Labelled
from zenoh_track.tracking.noise_check import NoiseCheck
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import (
    MSGPACK_ENCODING,
    Measurement,
    Rejected,
    pack,
    parse_full,
    parse_scan,
    parse_scan_columns,
    unpack,
)

NOISE = (10.0, 0.01, 0.01, 1.0)


def plain(r: np.ndarray, vel: np.ndarray, vel_cov: np.ndarray, sigma_t: np.ndarray
          ) -> np.ndarray:
    """The reference: row by row, R + s^2 (v v' + P_vv); R alone where s is NaN or 0."""
    out = r.copy()
    for i in range(len(r)):
        s = sigma_t[i]
        if s == s and s > 0:
            out[i] = r[i] + s * s * (np.outer(vel[i], vel[i]) + vel_cov[i])
    return out


def textbook(x: np.ndarray, p: np.ndarray, z: np.ndarray, r: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, float]:
    """One row's Kalman update by a position (H = [I 0]) and its Gaussian log-likelihood."""
    m = len(z)
    h = np.eye(m, len(x))
    s = h @ p @ h.T + r
    k = p @ h.T @ np.linalg.inv(s)
    nu = z - h @ x
    ll = -0.5 * (nu @ np.linalg.solve(s, nu) + np.log(np.linalg.det(s)) + m * np.log(2 * np.pi))
    return x + k @ nu, (np.eye(len(x)) - k @ h) @ p, ll


def plain_mixture(x: np.ndarray, p: np.ndarray, z: np.ndarray, r: np.ndarray,
                  term: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """One row's Gaussian-sum update: a component per (pi, s) of `defaults.TIME_MIXTURE`
    with noise R + s T, weighed by pi times its likelihood; their mean and covariance,
    and the log of the mixture's likelihood."""
    parts = [(pi, *textbook(x, p, z, r + s * term)) for pi, s in defaults.TIME_MIXTURE]
    lik = np.array([pi * math.exp(ll) for pi, _, _, ll in parts])
    w = lik / lik.sum()
    mean = sum(wc * xc for wc, (_, xc, _, _) in zip(w, parts, strict=True))
    cov = sum(wc * (pc + np.outer(xc - mean, xc - mean))
              for wc, (_, xc, pc, _) in zip(w, parts, strict=True))
    return mean, cov, math.log(lik.sum())


def spd(rng: np.random.Generator, n: int, d: int, scale: float) -> np.ndarray:
    a = rng.normal(size=(n, d, d)) * scale
    return a @ a.transpose(0, 2, 1) + np.eye(d) * scale


@pytest.mark.parametrize("d", [2, 3])
def test_time_noise_is_its_plain_form(d):
    rng = np.random.default_rng(0)
    n = 50
    r, cov = spd(rng, n, d, 30.0), spd(rng, n, d, 2.0)
    vel = rng.normal(0, 200, (n, d))
    sigma_t = rng.uniform(0, 0.5, n)
    sigma_t[::7], sigma_t[::11] = np.nan, 0.0
    want = plain(r, vel, cov, sigma_t)
    np.testing.assert_allclose(timing.time_noise(r, vel, cov, sigma_t), want, rtol=1e-13)
    none = ~(sigma_t > 0)
    assert (timing.time_term(vel, cov, sigma_t)[none] == 0.0).all()


def test_the_mixture_fits_the_student_t():
    """`defaults.TIME_MIXTURE` is the three-Gaussian scale mixture of variance 1 closest
    in Kullback-Leibler divergence to the Student t with 3 degrees of freedom of variance
    1 (fitted again here by quadrature, from a start away from it), far closer to it than
    a single Gaussian."""
    from scipy import integrate, optimize, stats

    nu = 3.0
    scale = math.sqrt((nu - 2.0) / nu)
    xs = np.linspace(0.0, 400.0, 200001)
    pt = stats.t.pdf(xs / scale, nu) / scale

    def mixture(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Probabilities and variances: the last variance makes the total 1."""
        w = np.exp(np.r_[v[:2], 0.0])
        w /= w.sum()
        a = np.exp(v[2:4])
        return w, np.r_[a, (1.0 - w[:2] @ a) / w[2]]

    def kl(w: np.ndarray, var: np.ndarray) -> float:
        if (var <= 0).any():
            return 1e3
        q = sum(wc * stats.norm.pdf(xs, 0, math.sqrt(vc)) for wc, vc in zip(w, var, strict=True))
        return 2 * integrate.trapezoid(pt * (np.log(pt) - np.log(q + 1e-300)), xs)

    w0, var0 = (np.array(c) for c in zip(*defaults.TIME_MIXTURE, strict=True))
    assert w0.sum() == pytest.approx(1.0, abs=1e-4) and w0 @ var0 == pytest.approx(1.0, 1e-3)
    got = optimize.minimize(lambda v: kl(*mixture(v)), [1.0, 0.0, -1.0, 0.5],
                            method="Nelder-Mead",
                            options={"xatol": 1e-7, "fatol": 1e-12, "maxiter": 4000})
    w, var = mixture(got.x)
    np.testing.assert_allclose(w, w0, rtol=0.02, atol=2e-3)
    np.testing.assert_allclose(var, var0, rtol=0.02)
    assert kl(w0, var0) < 1.01 * got.fun < 0.05 * kl(np.ones(1), np.ones(1))


@pytest.mark.parametrize("d", [2, 3])
def test_the_mixture_update_is_its_plain_form(d):
    """`timing.mixture_update` row by row against the textbook Gaussian sum; rows
    without time noise their plain update, bit for bit."""
    rng = np.random.default_rng(3)
    n, k = 30, 2 * d
    x = np.column_stack([rng.normal(0, 1e3, (n, d)), rng.normal(0, 200, (n, d))])
    p = spd(rng, n, k, 5.0)
    r = spd(rng, n, d, 3.0)
    sigma_t = rng.uniform(0.05, 0.3, n)
    sigma_t[::4] = np.nan
    term = timing.time_term(x[:, d:], p[:, d:, d:], sigma_t)
    # innovations along the track from the core to far in the tail
    z = x[:, :d] + x[:, d:] * rng.standard_t(3, n)[:, None] * np.nan_to_num(sigma_t)[:, None] \
        + rng.normal(0, 2, (n, d))
    some = sigma_t > 0
    xn, pn, ok, ll = timing.mixture_update(kalman.update_full, x, p, z, r, term, some)
    assert ok.all()
    for i in np.flatnonzero(some):
        want = plain_mixture(x[i], p[i], z[i], r[i], term[i])
        np.testing.assert_allclose(xn[i], want[0], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(pn[i], want[1], rtol=1e-9, atol=1e-9)
        assert ll[i] == pytest.approx(want[2], rel=1e-9)
    alone = kalman.update_full(x[~some], p[~some], z[~some], r[~some])
    assert np.array_equal(xn[~some], alone[0]) and np.array_equal(pn[~some], alone[1])
    assert np.array_equal(ll[~some], alone[4])


def batch_of(pos: np.ndarray, sigma: float, sigma_t: list[float | None], t: float
             ) -> MeasurementBatch:
    return MeasurementBatch.of([Measurement("s", f"a{i}", t, 3, False, tuple(p), (sigma,) * 3,
                                            (0.0,) * 3, None, st)
                                for i, (p, st) in enumerate(zip(pos, sigma_t, strict=True))], 3)


class Arrays:
    """A layout of rows as a filter reads it (x, p, t)."""

    dim, order = 3, 2

    def __init__(self, x: np.ndarray, p: np.ndarray) -> None:
        self.x, self.p, self.t = x, p, np.zeros(len(x))


def test_the_filter_core_updates_with_the_time_noise():
    """A single-model filter (`SingleModelFilter`, CV) updates by the time noise's
    mixture (`timing.mixture_update`) at the prediction; a row without sigma_t the
    plain update; the conversion the other filters call adds the mixture's variance."""
    rng = np.random.default_rng(1)
    n = 6
    x = np.column_stack([rng.normal(0, 1e3, (n, 3)), rng.normal(0, 200, (n, 3))])
    p = spd(rng, n, 6, 5.0)
    z = x[:, :3] + 2.0 * x[:, 3:] + rng.normal(0, 20, (n, 3))
    batch = batch_of(z, 3.0, [0.2, None, 0.0, 0.5, 0.1, None], 2.0)
    dt = np.full(n, 2.0)
    f = SingleModelFilter("cv", q=1.0)
    got = f.update(Arrays(x, p), np.arange(n), dt, CMKFConversion(batch))
    xp, pp = models.predict(x, p, dt, 2, 3, 1.0)
    r = np.broadcast_to(np.eye(3) * 9.0, (n, 3, 3))
    term = timing.time_term(xp[:, 3:], pp[:, 3:, 3:], batch.sigma_t)
    for i in range(n):
        want = plain_mixture(xp[i], pp[i], z[i], r[i], term[i])
        np.testing.assert_allclose(got[0][i], want[0], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(got[1][i], want[1], rtol=1e-9, atol=1e-9)
    total = plain(r, xp[:, 3:], pp[:, 3:, 3:], batch.sigma_t)
    np.testing.assert_allclose(got[2], kalman.update(xp, pp, z, total)[2], rtol=1e-9)
    np.testing.assert_allclose(CMKFConversion(batch)(xp, pp)[1], total, rtol=1e-12)


def test_a_position_late_in_time_moves_the_track_along_it_less():
    """Two tracks flying +x at 200 m/s; a measurement 40 m ahead of and one 40 m beside
    the prediction: with sigma_t 0.2 s the one ahead (40 m is 1 sigma of 0.2 s) moves
    the track a fraction of what the one beside does; without, both the same. One 200 m
    ahead (a repeat: 1 s late) moves it less than the one 40 m beside."""
    def moved(sigma_t: float | None, ahead: float = 40.0) -> tuple[float, float]:
        x = np.tile([0.0, 0.0, 1e3, 200.0, 0.0, 0.0], (2, 1))
        p = np.tile(np.diag([25.0] * 3 + [4.0] * 3), (2, 1, 1))
        z = np.array([[200.0 + ahead, 0.0, 1e3], [200.0, 40.0, 1e3]])
        out = SingleModelFilter("cv", q=0.1).update(
            Arrays(x, p), np.arange(2), np.ones(2),
            CMKFConversion(batch_of(z, 5.0, [sigma_t] * 2, 1.0)))[0]
        return out[0, 0] - 200.0, out[1, 1]
    ahead, beside = moved(None)
    assert ahead == pytest.approx(beside, rel=1e-9) and beside > 20.0
    ahead, beside = moved(0.2)
    assert beside > 20.0 and ahead < 0.35 * beside
    far, beside = moved(0.2, 200.0)
    assert 0 < far < beside


# ---------------------------------------------------------------- the wire
def test_a_measurement_states_its_time_noise():
    body = {"t": 1.0, "pos": [1.0, 2.0, 3.0], "sigma": 2.0}
    assert parse_full("s", "a", pack(body), NOISE).sigma_t is None
    assert parse_full("s", "a", pack({**body, "sigma_t": 0.15}), NOISE).sigma_t == 0.15
    polar = {"t": 1.0, "r": 1e3, "az": 0.1, "el": 0.05, "sigma_t": 0.0}
    assert parse_full("s", "a", pack(polar), NOISE).sigma_t == 0.0
    for bad, says in ((-0.1, "must be >= 0.0"), (float("nan"), "is not finite"),
                      (61.0, "must be <= 60.0"), ("0.1", "must be a number"),
                      (True, "must be a number")):
        with pytest.raises(Rejected, match=f"field 'sigma_t' {says}"):
            parse_full("s", "a", pack({**body, "sigma_t": bad}), NOISE)


def f64(values: list[float]) -> bytes:
    return struct.pack(f"<{len(values)}d", *values)


def test_a_batched_scan_states_its_time_noise():
    pos = f64([0.0, 0.0, 1e3, 100.0, 0.0, 1e3, 200.0, 0.0, 1e3])
    scan = {"t": 5.0, "ids": ["a", "b", "c"], "pos": pos, "dim": 3}
    assert parse_scan_columns("s", pack(scan), NOISE).sigma_t is None
    one = parse_scan_columns("s", pack({**scan, "sigma_t": 0.2}), NOISE)
    assert one.sigma_t == 0.2 and one.good == [0, 1, 2]
    assert MeasurementBatch.of_scan(one).sigma_t.tolist() == [0.2] * 3
    with pytest.raises(Rejected, match="field 'sigma_t' must be >= 0.0"):
        parse_scan_columns("s", pack({**scan, "sigma_t": -1.0}), NOISE)
    rows = {**scan, "sigma_t": f64([0.1, math.inf, 0.3])}
    cols = parse_scan_columns("s", pack(rows), NOISE)
    recs = parse_scan("s", pack(rows), NOISE)
    assert cols.good == [0, 2] and [m.sigma_t for m in recs.measurements] == [0.1, 0.3]
    assert cols.rejected == recs.rejected == [
        (1, "row 1 (b): field 'sigma_t' is not finite or out of bounds (inf)")]
    assert MeasurementBatch.of_scan(cols).sigma_t.tolist() == [0.1, 0.3]
    with pytest.raises(Rejected, match="bin 'sigma_t' has 16 bytes"):
        parse_scan_columns("s", pack({**scan, "sigma_t": f64([0.1, 0.2])}), NOISE)


# ---------------------------------------------------------------- the noise check
def feed_tracker(pos: np.ndarray, ts: np.ndarray, sigma: float, every: int = 1) -> Tracker:
    tr = Tracker.from_config(TrackerConfig())
    for k in range(0, len(ts), every):
        tr.step(Labelled.of([Measurement("feed", f"t{i}", float(ts[k]), 3, False,
                                         tuple(pos[i, k]), (sigma,) * 3, (0.0,) * 3, None)
                             for i in range(len(pos))]))
    return tr


def test_time_noise_is_told_from_position_noise():
    """Positions stated exact whose times are off by 0.1-0.2 s RMS (heavy-tailed):
    reported as time noise of about that size, the position noise as the small
    across-track one; the same aircraft with 20 m of isotropic jitter: position noise
    only, no time noise."""
    f = stamped.generate(aircraft=30, runs=1, seed=3, duration=120.0)
    rep = feed_tracker(f.pos, f.ts, 0.0, every=2).noise.status()["feed"]
    rms = float(np.sqrt(np.mean(f.sigma_t ** 2)))
    assert rep["direction"] == "too small" and rep["stated_t"] == 0.0
    assert 0.6 * rms < rep["measured_t"] < 1.2 * rms
    assert rep["measured"] < 5.0 and rep["along"] > 5 * rep["across"]
    rng = np.random.default_rng(4)
    jitter = np.round(f.truth + 20.0 * rng.standard_normal(f.truth.shape))
    rep = feed_tracker(jitter, f.ts, 0.0, every=2).noise.status()["feed"]
    assert "measured_t" not in rep and 14.0 < rep["measured"] < 26.0


def test_exact_positions_at_exact_times_report_nothing():
    f = stamped.generate(aircraft=20, runs=1, seed=5, duration=60.0)
    assert feed_tracker(f.truth, f.ts, 0.0).noise.status() == {}


def test_a_stated_time_noise_that_is_right_is_not_reported():
    check = NoiseCheck(min_count=30)
    f = stamped.generate(aircraft=30, runs=1, seed=6, duration=60.0)
    for k in range(len(f.ts)):
        b = batch_of(f.pos[:, k], 3.0, f.sigma_t.tolist(), float(f.ts[k]))
        check.observe("feed", [f"a{i}" for i in range(30)], np.arange(30), b,
                      np.full(30, 3.0), np.ones(30, bool))
    assert check.status() == {}


# ---------------------------------------------------------------- through the service
@pytest.mark.slow
@pytest.mark.parametrize("stated", [False, True])
def test_the_display_beats_linear_extrapolation_along_the_track(stated):
    """The stamped feed through the real service on loopback (lockstep), every other
    position sent stated exact (and with each aircraft's sigma_t), the frame 1 s later
    against the position held out: at most 0.8 x linear extrapolation's RMS, in turns
    too. Measured (`track-eval heldout --feed stamped --runs 1 --aircraft 100`): 0.67
    learned and 0.68 stated, turns 0.72; without the time noise's model 1.11."""
    f = stamped.generate(aircraft=100, runs=1, seed=7, duration=300.0)
    got = held.run_service(f.ts, f.pos, 0.0, [], f.sigma_t if stated else None)
    lin = held.linear(f.ts, f.pos)
    first = np.zeros(len(f.pos))
    for where in (None, f.turning):
        rms = held.score(got, f.pos, f.ts, first, where)
        assert rms["missing"] == 0
        assert rms["rms"] <= 0.8 * held.score(lin, f.pos, f.ts, first, where)["rms"]


@pytest.mark.slow
def test_service_reports_a_sensor_whose_times_jitter(service_factory):
    """20 aircraft at 1 Hz stated exact, their times off by 0.1-0.2 s: reported on
    `errors/<sensor>` (code `noise`) and in `status` with the time noise measured, the
    along-track jitter far beyond the across-track one; the stated sigma_t of a batched
    scan accepted, a bad one rejected with its reason."""
    svc, s = service_factory("--clock", "lockstep")
    errors = Collector(s, "track/errors/*")
    f = stamped.generate(aircraft=20, runs=1, seed=8, duration=40.0)
    enc, block = zenoh.Encoding(MSGPACK_ENCODING), zenoh.CongestionControl.BLOCK
    for k in range(len(f.ts)):
        for i in range(20):
            s.put(svc.keys.meas("adsb", f"a{i}"), pack({"t": float(f.ts[k]),
                                                        "pos": f.pos[i, k].tolist(),
                                                        "sigma": 0.0}),
                  encoding=enc, congestion_control=block)
    scan = {"t": 41.0, "ids": ["a0", "a1"], "pos": f64([*f.pos[0, -1], *f.pos[1, -1]]),
            "dim": 3, "sigma_t": f64([0.15, -1.0])}
    s.put(svc.keys.scan("adsb"), pack(scan), encoding=enc, congestion_control=block)
    s.put(svc.keys.clock, pack({"t": 42.0}), encoding=enc, congestion_control=block)
    assert errors.wait_for(lambda ss: any(b and b.get("code") == "noise" for _, _, b in ss))
    assert errors.wait_for(lambda ss: any(b and "sigma_t" in b.get("reason", "")
                                          and b.get("code") != "noise" for _, _, b in ss))
    body = next(b for _, _, b in errors.samples if b and b.get("code") == "noise")
    rms = float(np.sqrt(np.mean(f.sigma_t ** 2)))
    assert 0.5 * rms < body["measured_t"] < 1.3 * rms and body["stated_t"] == 0.0
    assert body["along"] > 5 * body["across"] and "times are off by about" in body["reason"]
    bad = next(b for _, _, b in errors.samples if b and "sigma_t" in b.get("reason", "")
               and b.get("code") != "noise")
    assert "row 1 (a1): field 'sigma_t' is not finite or out of bounds (-1.0)" in bad["reason"]
    status = unpack(next(iter(s.get(svc.keys.status, timeout=10))).ok.payload.to_bytes())
    assert status["sensor_noise"]["adsb"]["measured_t"] > 0.05


@pytest.mark.slow
def test_a_client_states_the_time_noise_it_knows(track):
    """The client library's feed sends `sigma_t` (a measurement, a batched scan), checked
    before sending; an aircraft flying +x at 200 m/s whose last position is 40 m ahead,
    stated 0.2 s late or early, moves its track along less than one 40 m beside."""
    feed = track.feed
    with pytest.raises(Rejected, match="field 'sigma_t' must be >= 0.0"):
        feed.measure("x", t=0.0, pos=[0.0, 0.0, 1e3], sigma_t=-0.1)
    for k in range(10):
        for name, dy in (("ahead", 0.0), ("beside", 5e3)):
            feed.measure(name, t=float(k), pos=[200.0 * k, dy, 1e3], sigma=5.0, sigma_t=0.2)
    feed.scan(10.0, ["ahead", "beside"], pos=np.array([[2040.0, 0.0, 1e3],
                                                       [2000.0, 5040.0, 1e3]]),
              sigma=5.0, sigma_t=np.array([0.2, 0.2]))
    frame = track.advance(10.0)
    ahead = frame.track("ahead")["pos"][0] - 2000.0
    beside = frame.track("beside")["pos"][1] - 5000.0
    assert 0.0 < ahead < 0.5 * beside
    assert track.client.status()["meas_accepted"] == 22
