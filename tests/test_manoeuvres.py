"""The `manoeuvres` scenario and what the default filter makes of it: the classes fly
the accelerations they are named for, Blair's NCV rule scales as it must, the IMM's
gate holds a 7 g turn's first scan that the single-model gate loses, and (slow) a
reduced `track-eval manoeuvres` through the service holds every aircraft with one
track at 1, 2 and 4 s scan periods."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from zenoh_track.clients.evaluation import evaluate as track_eval
from zenoh_track.clients.evaluation import manoeuvre_score as ms
from zenoh_track.clients.feeds.manoeuvres import CLASSES, SLOW_CLASSES, G, Manoeuvres
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.tracking import gating
from zenoh_track.tracking.batches import Unlabelled
from zenoh_track.tracking.tracker import Tracker
from zenoh_track.wire import Measurement


def test_each_class_flies_its_manoeuvre():
    sc = Manoeuvres(period=1.0, per_class=2, seed=3)
    assert [f.kind for f in sc.flights] == [k for k in CLASSES for _ in range(2)]
    ts = np.arange(0.0, 200.0, 0.25)
    expect = {"straight": 0.0, "standard-rate": 200 * math.radians(3), "4g": 4 * G,
              "7g-s": 7 * G, "climbing": 200 * math.radians(6)}
    for f in sc.flights:
        states = [f.state(t) for t in ts]
        acc = np.array([np.linalg.norm(s[2][:2]) for s in states])
        speed = np.array([np.linalg.norm(s[1][:2]) for s in states])
        assert acc.max() == pytest.approx(expect[f.kind], rel=1e-9), f.name
        assert np.ptp(speed) < 1e-6 * speed[0]  # coordinated turns: constant speed
        assert not acc[ts < 60].any() and not any(f.manoeuvring(t) for t in ts[ts < 60])
        # the position is the integral of the velocity (the closed form is right)
        pos = np.array([s[0] for s in states])
        vel = np.array([s[1] for s in states])
        mid = 0.5 * (vel[1:] + vel[:-1]) * 0.25
        np.testing.assert_allclose(np.diff(pos, axis=0), mid, atol=0.25**3 * acc.max())
    climb = next(f for f in sc.flights if f.kind == "climbing")
    assert max(climb.state(t)[1][2] for t in ts) == pytest.approx(30.0)
    assert climb.state(199.0)[1][2] == pytest.approx(0.0, abs=1e-9)
    s_turn = next(f for f in sc.flights if f.kind == "7g-s")
    signs = {np.sign(s_turn.state(t)[1][0] * s_turn.state(t)[2][1]
                     - s_turn.state(t)[1][1] * s_turn.state(t)[2][0]) for t in ts}
    assert signs == {-1.0, 0.0, 1.0}  # turns both ways


def test_slow_flyers_turn_tight():
    """The slow and tight classes on request: a 60 m/s orbit at 6 deg/s, a 40 m/s
    helicopter at 12 deg/s both ways, a 30 m/s glider circling five times at 15 deg/s
    while climbing 2 m/s; coordinated, so constant speed and v omega of acceleration."""
    sc = Manoeuvres(period=1.0, per_class=1, seed=5, classes=SLOW_CLASSES)
    assert [f.kind for f in sc.flights] == list(SLOW_CLASSES)
    ts = np.arange(0.0, 200.0, 0.25)
    rate = {"orbit": (60.0, 6.0), "helicopter": (40.0, 12.0), "glider": (30.0, 15.0)}
    for f in sc.flights:
        v, deg = rate[f.kind]
        states = [f.state(t) for t in ts]
        acc = np.array([np.linalg.norm(s[2][:2]) for s in states])
        speed = np.array([np.linalg.norm(s[1][:2]) for s in states])
        assert acc.max() == pytest.approx(v * math.radians(deg), rel=1e-9), f.name
        assert np.ptp(speed) < 1e-6 * v and speed[0] == pytest.approx(v)
    glider = sc.flights[2]
    heading = [math.atan2(glider.state(t)[1][1], glider.state(t)[1][0]) for t in ts]
    turned = np.abs(np.diff(np.unwrap(heading))).sum()
    assert math.degrees(turned) == pytest.approx(1800.0, rel=1e-3)
    assert glider.state(150.0)[1][2] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="unknown class"):
        Manoeuvres(classes=("jet",))


def test_scans_detect_with_pd_and_add_clutter():
    sc = Manoeuvres(period=2.0, pd=0.8, clutter=5.0, per_class=4, seed=1)
    scans = list(sc)
    assert [s.t for s in scans] == list(np.arange(0.0, 201.0, 2.0))
    real = np.concatenate([s.origin for s in scans])
    assert abs((real >= 0).sum() / (20 * len(scans)) - 0.8) < 0.04
    assert abs((real < 0).sum() / len(scans) - 5.0) < 0.7
    labelled = list(sc.labelled())
    assert sum(len(m) for _, m, _ in labelled) == (real >= 0).sum()


def test_blair_rule_scales_with_the_acceleration_and_the_noise():
    """q (m/s^2) is a function of the tracking index a T^2 / sigma times sigma / T^2:
    scaling the acceleration and the noise together scales q."""
    q = ms.blair_q(7 * G, 2.0, 54.0)
    assert ms.blair_q(14 * G, 2.0, 108.0) == pytest.approx(2 * q, rel=1e-3)
    assert ms.blair_q(7 * G, 4.0, 54.0) < q  # longer scans, lower noise per second


def _first_turn_scan(tracker: Tracker, period: float) -> tuple[np.ndarray, Measurement]:
    """Straight flight at 250 m/s for 40 s, then the detection of a 7 g turn's first scan."""
    r0 = np.array([20_000.0, 30_000.0, 5_000.0])
    v = np.array([250.0, 0.0, 0.0])
    rng = np.random.default_rng(0)

    def meas(t: float, p: np.ndarray) -> Measurement:
        return Measurement("r", "", t, 3, False, tuple(p + rng.normal(0, 20.0, 3)),
                           (20.0,) * 3, (0.0, 0.0, 0.0), None)

    ts = np.arange(0.0, 40.0 + 1e-9, period)
    for t in ts:
        tracker.step(Unlabelled.of("r", float(t), [meas(float(t), r0 + v * t)]))
    t = float(ts[-1] + period)
    turned = r0 + v * t + np.array([0.0, 0.5 * 7 * G * period**2, 0.0])
    return ts, meas(t, turned)


def test_the_imm_gate_holds_the_first_scan_of_a_7g_turn():
    """Gated with the IMM's widest mode, a detection 550 m off the straight prediction
    (7 g for 4 s) is in the gate; gated with the combined state and the nominal noise,
    as before, it is not."""
    tracker = Tracker.from_config()
    ts, m = _first_turn_scan(tracker, 4.0)
    arrays = tracker.store.layout(3)
    rows = arrays.rows()[arrays.confirmed[arrays.rows()]]
    assert len(rows) == 1
    z, r = gating.convert(MeasurementBatch.of([m], 3))
    gamma = gating.gate_threshold(0.999, 3)
    imm = tracker.updater
    assert len(gating.gate(arrays, rows, z, r, m.t, 1.0, gamma, imm.gate_prediction).ti) == 1
    assert len(gating.gate(arrays, rows, z, r, m.t, 1.0, gamma).ti) == 0
    # the gate's mean is the mixture's: the straight prediction, not the wide mode's own
    mean, cross, _ = imm.gate_prediction(arrays, rows, m.t)
    np.testing.assert_allclose(mean[0], arrays.x[rows[0], :3] + arrays.x[rows[0], 3:6] * 4.0,
                               atol=1.0)
    assert cross.shape == (1, 3, 9)


@pytest.mark.slow
def test_every_aircraft_held_with_one_track(capsys):
    """A reduced `track-eval manoeuvres` (one run, one aircraft a class) through the
    service without options: no track break, every aircraft held at >= 98 % of its scans
    from confirmation on, at 1, 2, 4 and 5 s."""
    held_with_one_track(capsys, CLASSES, (1, 2, 4, 5))


def held_with_one_track(capsys, classes: tuple[str, ...], periods: tuple[int, ...],
                        *extra: str) -> None:
    """A reduced `track-eval manoeuvres` of `classes` at `periods` (s): no class of any
    period broke a track or held an aircraft at fewer than 98 % of its scans."""
    track_eval.main(["manoeuvres", "--runs", "1", "--per-class", "1", "--config", "default",
                     "--classes", ",".join(classes),
                     *[a for p in periods for a in ("--period", str(p))], *extra, "--json"])
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {f"default {p} s" for p in periods}
    for label, sums in out.items():
        assert set(sums) == set(classes)
        for kind, row in sums.items():
            assert row["never"] == 0 and row["breaks"] == 0, (label, kind, row)
            assert row["held_min"] >= 0.98, (label, kind, row)


@pytest.mark.slow
def test_slow_flyers_held_with_one_track(capsys):
    """The slow and tight flyers (orbit, helicopter, glider) through the service without
    options, one run at 1 and 4 s: no break, every scan held from confirmation."""
    held_with_one_track(capsys, SLOW_CLASSES, (1, 4))


@pytest.mark.slow
def test_the_own_rate_turn_option_holds_every_aircraft(capsys):
    """`--imm-turn-estimated 5` (a seventh mode turning at its own rate, compiled)
    through the service, one run at 1 and 4 s: no break, every aircraft held."""
    held_with_one_track(capsys, CLASSES, (1, 4), "--service-arg=--imm-turn-estimated=5")


@pytest.mark.slow
def test_eval_prints_where_the_nees_comes_from(capsys):
    """`track-eval manoeuvres --onset`: after each class table, the manoeuvring samples
    by scans since their onset, every manoeuvring class and scan row present."""
    track_eval.main(["manoeuvres", "--runs", "1", "--per-class", "1", "--config", "default",
                     "--classes", "straight,4g", "--period", "4", "--onset"])
    lines = capsys.readouterr().out.splitlines()
    head = next(i for i, line in enumerate(lines) if line.split()[:2] == ["class", "scan"])
    rows = [line.split() for line in lines[head + 1:] if line.strip()]
    assert rows and {r[0] for r in rows} == {"4g"}  # straight flight has no onset
    assert [r[1] for r in rows] == sorted({r[1] for r in rows}, key=lambda k: int(k[:1]))
    assert sum(float(r[5]) for r in rows) == pytest.approx(1.0, abs=0.02)


@pytest.mark.slow
def test_jpda_holds_every_aircraft_with_one_track(capsys):
    """The same through the service with `--associator jpda`: no track break at 1 to 5 s
    (its speed gate; docs/explanation/association.md)."""
    track_eval.main(["manoeuvres", "--runs", "1", "--per-class", "1", "--config", "default",
                     "--service-arg=--associator=jpda", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert len(out) == 4
    for label, sums in out.items():
        for kind, row in sums.items():
            assert row["never"] == 0 and row["breaks"] == 0, (label, kind, row)


@pytest.mark.parametrize("gate_wide, taken", [(None, False), (1.0, True)])
def test_a_coasting_track_leaves_far_clutter_in_its_wide_gate(gate_wide, taken):
    """A track that missed a 4 s scan has a gate of kilometres (its widest mode over
    8 s, 34 m/s^2 there: `defaults.IMM_WIDE_DV`); a false detection 4 km off is in it.
    Scored under the widest mode alone (`gate_wide` 1) the track takes it; under the
    IMM's two-component likelihood (the default) it is left to start a track of its own
    (the second look off and targets up to 2,000 m/s, beyond the speed gate's reach: this
    is the likelihood's doing alone)."""
    import dataclasses

    from zenoh_track.tracking.plot_association import SensorModels
    from zenoh_track.tracking.tracker import TrackerConfig

    config = TrackerConfig(sensors=SensorModels(clutter_density=9e-14), second_look=0.0,
                           max_speed=2000.0)
    built = config.filter.build()
    if gate_wide is not None:
        built = dataclasses.replace(built, updater=dataclasses.replace(built.updater,
                                                                       gate_wide=gate_wide))
    tracker = Tracker.from_config(config, filter=built)
    ts, m = _first_turn_scan(tracker, 4.0)
    arrays = tracker.store.layout(3)
    row = int(arrays.rows()[arrays.confirmed[arrays.rows()]][0])
    t = float(ts[-1] + 8.0)  # the scan at ts[-1] + 4 missed
    tracker.step(Unlabelled.of("r", float(ts[-1] + 4.0), []))
    x = arrays.x[row]
    far = x[:3] + x[3:6] * 8.0 + np.array([0.0, 4000.0, 0.0])
    clutter = Measurement("r", "", t, 3, False, tuple(far), (20.0,) * 3, (0.0, 0.0, 0.0), None)
    z, r = gating.convert(MeasurementBatch.of([clutter], 3))
    g = gating.gate(arrays, np.array([row]), z, r, t, 1.0, gating.gate_threshold(0.999, 3),
                    tracker.updater.gate_prediction)
    assert len(g.ti) == 1  # in the gate either way
    tracker.step(Unlabelled.of("r", t, [clutter]))
    assert (arrays.t[row] == t) == taken


def test_imm_onset_option_sets_the_rate_of_entering_the_manoeuvre_modes():
    """`--imm-onset` (docs/accuracy.md: a user who tracks fighters trades B's bars for
    the manoeuvring NEES) builds the IMM of `ModeSet(onset=...)`; without it, the
    default's."""
    from zenoh_track.__main__ import parser, tracker_config
    from zenoh_track.estimation.imm import ModeSet
    from zenoh_track.estimation.imm_jit import CompiledIMM

    def built(argv: list[str]):
        return tracker_config(parser().parse_args(argv)).filter.build().updater

    fast = built(["--imm-onset", "60"])
    assert fast == ModeSet(onset=60.0).imm(CompiledIMM)  # the catalogue's: compiled
    assert built([]) == ModeSet().imm(CompiledIMM) != fast
    turning = built(["--imm-turn-estimated", "5"])  # a seventh mode at its own rate
    assert turning == ModeSet(manoeuvre=(*ModeSet().manoeuvre, ("turn", 5.0))).imm(CompiledIMM)
    assert [m[1] for m in turning.modes].count("turn") == 1
    for bad in (["--imm-onset", "0"], ["--imm-onset", "-5"], ["--imm-sojourn", "inf"],
                ["--second-look", "nan"], ["--imm-turn-estimated", "-1"],
                ["--imm-turn-estimated", "nan"]):  # a clear error (exit 2), not a traceback
        with pytest.raises(SystemExit) as stop:
            parser().parse_args(bad)
        assert stop.value.code == 2


@pytest.mark.parametrize("exit_quiet", [0.0, 0.05, 0.2])
def test_a_manoeuvre_mode_is_left_half_for_steady_flight(exit_quiet):
    """A manoeuvre mode is left in `turn_sojourn` s (a turn at a known rate in
    `ct_sojourn` s): half of it for the quiet and nominal modes (`exit_quiet` for the
    quiet one: an aircraft back on steady flight), the rest for the CA and the other
    manoeuvre modes; the other modes' exits are unchanged."""
    from zenoh_track.estimation.imm import ModeSet

    imm = ModeSet(exit_quiet=exit_quiet, turn_sojourn=7.0, ct_sojourn=40.0).imm()
    names = [m[0] for m in imm.modes]
    leave = np.array(imm.leave)
    assert names[:3] == ["quiet", "cv", "ca"] and len(names) > 4
    kinds = [m[1] for m in imm.modes]
    assert "ct" in kinds[3:] and "cv" in kinds[3:]
    for i in range(3, len(names)):  # the manoeuvre modes
        assert imm.sojourn[i] == pytest.approx(40.0 if kinds[i] == "ct" else 7.0)
        assert leave[i, names.index("quiet")] == pytest.approx(exit_quiet)
        assert leave[i, names.index("cv")] == pytest.approx(0.5 - exit_quiet)
        assert leave[i].sum() == pytest.approx(1.0) and leave[i, i] == 0.0
    base = np.array(ModeSet(exit_quiet=0.0).imm().leave)
    np.testing.assert_array_equal(leave[:3], base[:3])


@pytest.mark.parametrize("entry", [1.0, 3.0])
def test_the_turns_at_a_known_rate_are_entered_ct_entry_times_as_often(entry):
    """Every chained mode enters the manoeuvre modes at 1 / `onset` in all, a "ct" one
    `ct_entry` times as often as the others (the chained modes' own exits unchanged)."""
    from zenoh_track.estimation.imm import ModeSet

    imm = ModeSet(ct_entry=entry, onset=1000.0).imm()
    kinds = [m[1] for m in imm.modes]
    k = len(kinds) - 3
    rate = np.array(imm.leave) / np.array(imm.sojourn)[:, None]  # per second, i -> j
    for i in range(3):
        for j in range(3, len(kinds)):
            want = (entry if kinds[j] == "ct" else 1.0) / 1000.0 / k
            assert rate[i, j] == pytest.approx(want)


def test_the_onset_profile_splits_the_manoeuvring_samples_by_scans_since_the_onset():
    """`Flight.leg_age` counts from the start of the current leg (a turn, a reversal);
    `onset_table` bins the manoeuvring samples by it: each sample once, the NEES shares
    of a class summing to 1."""
    from zenoh_track.clients.feeds.manoeuvres import LEAD

    sc = Manoeuvres(2.0, 0.9, 0.0, 1, 0, classes=("7g-s",))
    f = sc.flights[0]
    w = 7 * G / 250.0
    assert f.leg_age(LEAD + 1.0) == pytest.approx(1.0)
    assert f.leg_age(LEAD + math.pi / 2 / w + 0.5) == pytest.approx(0.5)  # the reversal
    truth = {round(t, 6): f.state(t) for t in sc.times.tolist()}
    shown = {t: {"a": s[0] + 10.0} for t, s in truth.items()}  # 10 m off on each axis
    cov = np.eye(6) * 100.0
    states = {t: {"a": (np.concatenate([s[0] + 10.0, s[1]]), cov)} for t, s in truth.items()}
    got = ms.score(sc, shown, states)
    man = [s for a in got for s in a.onset]
    assert len(man) == sum(f.manoeuvring(t) for t in sc.times.tolist()) > 0
    assert all(e == pytest.approx(300.0) and n == pytest.approx(3.0) for _, e, n in man)
    rows = [r.split() for r in ms.onset_table(got, 2.0, scans=3).splitlines()[1:]]
    assert sum(int(r[2]) for r in rows) == len(man)
    assert sum(float(r[5]) for r in rows) == pytest.approx(1.0, abs=0.02)
    assert {r[1] for r in rows} == {"0", "1", "2", "3+"}
