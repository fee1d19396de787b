"""Unit tests of the display state's blending (pure NumPy through the Tracker, no Zenoh).

Frames are drawn as the lockstep service draws them: every display instant before a
measurement's time is drawn from the states held before it is applied."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import make_tracker as make
from reference.record import track

from zenoh_track.tracking import display
from zenoh_track.tracking.tracker import Tracker
from zenoh_track.wire import Measurement

RATE = 30.0


def cart(target, t, pos):
    return Measurement("s1", target, float(t), 3, False, tuple(map(float, pos)),
                       (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), None)


def replay(config: dict, jumps: dict[str, float], t_jump: float = 4.0,
           t_end: float = 5.0) -> tuple[Tracker, np.ndarray, dict[str, np.ndarray],
                                        dict[str, list[str]]]:
    """Targets at 10 m/s along x, measured exactly at 1 Hz up to t_jump, where each
    target's measurement is displaced by jumps[target] metres along y (an unmodelled
    manoeuvre). Returns the table, frame instants in [3 s, t_end) and per target the
    drawn positions and what each frame shows."""
    table = make(**config)
    n = 3 * int(RATE)
    drawn: dict[str, list[np.ndarray]] = {k: [] for k in jumps}
    shown: dict[str, list[str]] = {k: [] for k in jumps}
    instants = []

    def frames_until(t: float) -> None:
        nonlocal n
        while n / RATE < t - 1e-6:
            snap = table.snapshot(n / RATE)
            for k in jumps:
                i = snap.ids.index(k)
                drawn[k].append(snap.pos[i].copy())
                shown[k].append(snap.shown[i])
            instants.append(n / RATE)
            n += 1

    for k in range(int(t_jump) + 1):
        if k > 3:
            frames_until(k)
        track(table, [cart(name, k, (10.0 * k, d if k >= t_jump else 0.0, 0.0))
                     for name, d in jumps.items()])
    frames_until(t_end)
    return table, np.array(instants), {k: np.array(v) for k, v in drawn.items()}, shown


def estimate(table: Tracker, name: str, t: np.ndarray) -> np.ndarray:
    """The filter's own prediction of a track (what plain prediction draws)."""
    arrays, row = table.store.where[name]
    rows = np.full(len(t), row)
    axis_cov = table.display.columns(arrays).axis_cov[rows]
    xs, _ = display.predicted(arrays.x[rows], arrays.t[rows], axis_cov, t, table.display.q,
                              arrays.order, arrays.dim)
    return xs[:, 0]


def test_frame_before_is_the_last_instant_strictly_before():
    got = display.frame_before(np.array([6.0, 6.0 + 5e-7, 6.01, 6.0 + 1 / 30]), 30.0)
    np.testing.assert_allclose(got * 30.0, [179, 179, 180, 180])


def test_blend_period_speed_period_and_both():
    off = np.array([[0.3, 0.4, 0.0], [0.0, 0.0, 0.0], [3.0, 4.0, 0.0]])  # 0.5, 0, 5 m
    np.testing.assert_allclose(display.blend_period(off, 0.0, 2.0), [0.25, 0.0, 2.5])
    np.testing.assert_allclose(display.blend_period(off, 0.35, 0.0), [0.35, 0.0, 0.35])
    np.testing.assert_allclose(display.blend_period(off, 1.0, 2.0), [0.25, 0.0, 1.0])


def test_speed_limit_bounds_every_step_and_absorbs_small_corrections_at_once():
    speed = 2.4
    jumps = {"big": 0.9, "small": 0.05, "none": 0.0}  # three rows of one bank
    table, t, drawn, shown = replay(dict(order=2, q=0.1, blend_speed=speed), jumps)
    after = t >= 4.0 - 1e-9
    step_max = speed / RATE
    for name in jumps:
        est = estimate(table, name, t[after])
        # every frame's step beyond the estimate's own motion is at most speed / rate,
        # including the first one, from the last frame drawn before the correction
        rel = drawn[name][after] - est
        first = drawn[name][~after][-1] - estimate(table, name, t[~after][-1:])[0]
        steps = np.linalg.norm(np.diff(np.vstack([first, rel]), axis=0), axis=1)
        assert steps.max() <= step_max + 1e-9, name
        # the correction is gone after |offset| x rate / speed frames (counted from the
        # last frame before it), not after a fixed period
        size = np.linalg.norm(first)
        frames = max(math.ceil(size * RATE / speed - 1e-9) - 1, 0)
        assert (np.linalg.norm(rel, axis=1)[frames:] < 1e-9).all(), name
        kinds = np.array(shown[name])[after]
        assert (kinds[:frames] == "blend").all() and (kinds[frames:] == "prediction").all()
    big = np.linalg.norm(drawn["big"][after] - estimate(table, "big", t[after]), axis=1)
    assert 9 <= np.count_nonzero(big > 1e-9) <= 12  # 0.9 m at 0.08 m per frame
    np.testing.assert_allclose(np.diff(big[:8]), -step_max, atol=1e-9)  # constant speed
    assert shown["small"][np.flatnonzero(after)[0]] == "prediction"  # absorbed at once
    assert set(shown["none"]) == {"prediction"}


def test_fixed_period_holds_every_correction_equally_long():
    jumps = {"big": 0.9, "small": 0.05}
    table, t, _, shown = replay(dict(order=2, q=0.1, blend=0.35), jumps)
    after = t >= 4.0 - 1e-9
    counts = {k: int((np.array(v)[after] == "blend").sum()) for k, v in shown.items()}
    assert counts["big"] == counts["small"] == math.ceil(0.35 * RATE) - 1


@pytest.mark.parametrize("config", [dict(blend_speed=2.4), dict(blend=0.35),
                                    dict(blend_speed=2.4, blend=0.21)])
def test_blending_leaves_the_filter_output_alone(config):
    jumps = {"a": 0.9}
    plain, t, drawn_plain, _ = replay(dict(order=2, q=0.1), jumps)
    blended, _, drawn, _ = replay(dict(order=2, q=0.1, **config), jumps)
    assert plain.state("a") == blended.state("a")  # tracks/ carries the raw filter output
    before = t < 4.0 - 1e-9
    np.testing.assert_allclose(drawn["a"][before], drawn_plain["a"][before], atol=1e-6)
    np.testing.assert_allclose(drawn["a"][-1], drawn_plain["a"][-1], atol=1e-12)


def test_period_caps_the_speed_limit():
    jumps = {"a": 0.9}
    _, t, _, shown = replay(dict(order=2, q=0.1, blend_speed=2.4, blend=0.21), jumps)
    after = t >= 4.0 - 1e-9
    assert int((np.array(shown["a"])[after] == "blend").sum()) == math.ceil(0.21 * RATE) - 1


def test_tentative_tracks_snap_to_their_first_estimates():
    # a CA track is tentative until its third update: the one-point start (velocity 0)
    # is no display state worth blending from, so the second update is drawn at once
    table = make(order=3, q=0.5, blend_speed=2.4)
    track(table, [cart("a", 0.0, (0.0, 0.0, 0.0))])
    track(table, [cart("a", 1.0, (10.0, 0.0, 0.0))])
    snap = table.snapshot(1.0)
    assert snap.shown == ["prediction"]
    np.testing.assert_allclose(snap.pos[0], [10.0, 0.0, 0.0], atol=1e-9)
    track(table, [cart("a", 2.0, (20.0, 0.0, 0.0))])
    track(table, [cart("a", 3.0, (31.0, 0.0, 0.0))])  # confirmed: a 1 m surprise blends
    assert table.snapshot(3.0).shown == ["blend"]


@pytest.mark.parametrize("order, dim", [(3, 3), (3, 2), (2, 3), (2, 2)])
def test_frame_prediction_is_the_reference_prediction(order, dim):
    """`predicted_at` (the frames' fast form, chunked) against `predicted` (Phi x and
    c0' A c0 term by term): the same positions, velocities and variances to rounding,
    over more rows than one chunk, dt of both signs."""
    rng = np.random.default_rng(order * 10 + dim)
    n_rows, n = display.FRAME_CHUNK * 2 + 37, order * dim
    x = rng.normal(0, 100, (n_rows, n))
    a = rng.normal(0, 1, (n_rows, n, n))
    p = a @ a.transpose(0, 2, 1) + np.eye(n)
    axis_cov = display.axis_traces(p, order, dim)
    t_state = rng.uniform(-2, 3, n_rows)
    pos, vel, var = display.predicted_at(x, t_state, axis_cov, 1.25, 0.7, order, dim)
    xs, ref_var = display.predicted(x, t_state, axis_cov, 1.25, 0.7, order, dim)
    np.testing.assert_allclose(pos[:, :dim], xs[:, 0], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(vel[:, :dim], xs[:, 1], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(var, ref_var, rtol=1e-12)
    assert not pos[:, dim:].any() and not vel[:, dim:].any()


def test_frame_is_the_imm_prediction_but_for_the_manoeuvre_mode_switching():
    """The frame predicts the IMM's combined estimate with one model (F of CA on the
    combined state). The IMM's own predicted mean, the mixture of its modes' predictions,
    differs from it exactly by (mu_CA - c_CA) a_CA dt^2 / 2 in position and
    (mu_CA - c_CA) a_CA dt in velocity (the frame's draw, service/tracking/frame.py), less each turn
    mode's c_j (F_CT - F_CV) x0_j: the CV modes hold no acceleration, and mixing keeps the
    mean. |c_CA - mu_CA| <= 1 - exp(-dt / 10 s) with the default sojourns (the CA mode's,
    10 s, beside its onset of the manoeuvre modes)."""
    from zenoh_track.estimation import models

    tracker = Tracker.from_config()
    for k in range(6):  # accelerating targets: the CA mode gains weight
        track(tracker, [cart(f"a{i}", k, (100.0 * k + 4.0 * i * k * k, 50.0 * i, 0.0))
                       for i in range(8)])
    arrays = tracker.store.layout(3)
    rows = arrays.live()[0]
    imm = tracker.updater
    ca = [kind for _, kind, _, _ in imm.modes].index("ca")
    for dt in (0.2, 1.0, 3.0):
        t = float(arrays.t[rows].max()) + dt
        dts = t - arrays.t[rows]
        c, x0, _ = imm.mix(arrays.mode_x[rows], arrays.mode_p[rows], arrays.mode_prob[rows],
                           imm.transition(dts), 3)
        mean, turned = np.zeros((len(rows), 9)), np.zeros((len(rows), 9))
        for j, (_, kind, q, omega) in enumerate(imm.modes):
            f, _ = models.motion(kind, dts, 3, 3, q, omega)
            mean += c[:, j, None] * (f @ x0[:, j, :, None])[:, :, 0]
            if kind == "ct":  # what the turn adds to the straight line
                straight, _ = models.motion("cv", dts, 3, 3, q, 0.0)
                turned += c[:, j, None] * ((f - straight) @ x0[:, j, :, None])[:, :, 0]
        pos, vel, _ = display.predicted_at(arrays.x[rows], arrays.t[rows],
                                           tracker.display.columns(arrays).axis_cov[rows], t,
                                           tracker.display.q, 3, 3)
        gap = (arrays.mode_prob[rows, ca] - c[:, ca])[:, None] * arrays.mode_x[rows, ca, 6:9]
        np.testing.assert_allclose(pos - mean[:, :3] + turned[:, :3], gap * dts[:, None] ** 2 / 2,
                                   atol=1e-6)
        np.testing.assert_allclose(vel - mean[:, 3:6] + turned[:, 3:6], gap * dts[:, None],
                                   atol=1e-8)
        assert (np.abs(c[:, ca] - arrays.mode_prob[rows, ca])
                <= 1 - np.exp(-dts / imm.sojourn[ca])).all()
        assert np.abs(gap).max() > 0  # the test sees a manoeuvre mode at work
