"""The second look (tracking.second_look): a confirmed track's doubtful detection waits one
scan, and the next scan chooses between taking it and having missed. The default filter
(the IMM), unlabelled 3-D detections every 4 s, as in the manoeuvres scenario's breaks at 4 s."""

from __future__ import annotations

import manoeuvre_runs
import numpy as np
import pytest
from reference.record import Outcome, scan_step

from zenoh_track import defaults
from zenoh_track.tracking import gating
from zenoh_track.tracking.batches import Unlabelled
from zenoh_track.tracking.plot_association import SensorModels, miss_score
from zenoh_track.tracking.second_look import SecondLook
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import Measurement

SIGMA, PERIOD, SPEED, PD, DENSITY = 50.0, 4.0, 200.0, 0.9, 4e-14
START = np.array([30_000.0, 5_000.0, 8_000.0])
VEL = np.array([0.0, SPEED, 0.0])


def det(t: float, pos) -> Measurement:
    return Measurement("r1", "", float(t), 3, False, tuple(float(v) for v in pos),
                       (SIGMA,) * 3, (0.0, 0.0, 0.0), None)


def step(tracker: Tracker, t: float, positions) -> list[Outcome]:
    outcomes = [Outcome(det(t, p)) for p in positions]
    scan_step(tracker, outcomes, t)
    return outcomes


def second_look(tracker: Tracker) -> SecondLook:
    """The tracker's second-look stage (its doubts and counts)."""
    return next(s for s in tracker.scan_associator.stages if isinstance(s, SecondLook))


def settled(margin: float, density: float = DENSITY, max_accel: float = defaults.MAX_ACCEL
            ) -> tuple[Tracker, str, float]:
    """A confirmed track on a straight flight, 15 scans; its id and the last scan's time.
    Targets up to 1,000 m/s: the doubtful offsets (about 2 km in 4 s) within the speed
    gate (`stages.SpeedGate`), which at the default 340 m/s takes none of them; the second
    look's reach `max_accel` (the stitcher's the default)."""
    tracker = Tracker.from_config(TrackerConfig(
        sensors=SensorModels(PD, density), second_look=margin, max_speed=1000.0,
        max_accel=max_accel, stitch_reach=defaults.MAX_ACCEL))
    for k in range(15):
        step(tracker, k * PERIOD, [START + VEL * k * PERIOD])
    (track,) = tracker.store.where
    assert tracker.store.where[track][0].confirmed[tracker.store.where[track][1]]
    return tracker, track, 14 * PERIOD


def doubtful_offset(tracker: Tracker, track: str, t: float) -> float:
    """A cross-track offset at which a lone detection beats a miss by less than 2 (ln):
    searched with the tracker's own gate and scores, outward from the prediction."""
    arrays, row = tracker.store.where[track]
    rows = np.array([row])
    gate_fn = tracker.scan_associator.predict
    miss = miss_score(PD)
    pred = START + VEL * t
    for dy in np.arange(200.0, 5000.0, 10.0):
        z = (pred + [dy, 0.0, 0.0])[None]
        g = gating.gate(arrays, rows, z, np.eye(3)[None] * SIGMA**2, t, 1.0,
                        gating.gate_threshold(0.999, 3), gate_fn)
        if len(g.ti):
            margin = float(np.log(PD) + g.loglik[0] - np.log(DENSITY)) - miss
            if 0.0 < margin < 2.0:
                return float(dy)
    raise AssertionError("no doubtful offset found")


def shown_at(tracker: Tracker, track: str, t: float) -> np.ndarray:
    """Where the display draws the track at t (a frame's snapshot)."""
    snap = tracker.snapshot(t)
    return np.asarray(snap.pos[snap.ids.index(track)])


def state(tracker: Tracker, track: str) -> tuple[np.ndarray, np.ndarray]:
    s = tracker.state(track)
    return np.array(s["pos"]), np.array(s["vel"])


def test_clutter_taken_in_a_missed_scan_is_undone_by_the_next():
    """Scan k: the aircraft is not detected; a false detection far out in the widest gate
    beats a miss by a hair and the track takes it. Scan k+1: the aircraft where it flies.
    The second look puts the track back on its miss branch and gives it the detection:
    one track, on the aircraft, with its velocity; without it (margin 0) the track keeps
    the jump's velocity."""
    results = {}
    for margin in (3.0, 0.0):
        tracker, track, t = settled(margin)
        t1, t2 = t + PERIOD, t + 2 * PERIOD
        dy = doubtful_offset(tracker, track, t1)
        step(tracker, t1, [START + VEL * t1 + [dy, 0.0, 0.0]])
        shown = shown_at(tracker, track, t1)
        if margin:  # in doubt: shown and kept on its miss branch, coasting
            assert tracker.state(track)["t"] == t
            assert np.linalg.norm(shown - (START + VEL * t1)) < 0.1 * dy
        else:  # committed at once: the jump shows
            assert np.linalg.norm(shown - (START + VEL * t1)) > 0.5 * dy
        step(tracker, t2, [START + VEL * t2])
        pos, vel = state(tracker, track)
        results[margin] = (np.linalg.norm(pos - (START + VEL * t2)),
                           np.linalg.norm(vel - VEL), sorted(tracker.store.where),
                           tracker.counts()["reverted"])
    err, verr, ids, reverted = results[3.0]
    assert ids == [track] and reverted == 1
    assert err < 3 * SIGMA and verr < 30.0
    assert results[0.0][3] == 0 and results[0.0][1] > 3 * verr  # the jump's velocity kept
    assert len(results[0.0][2]) == 2  # and the aircraft started a second track: a break


def test_a_turn_confirmed_by_the_next_scan_is_kept():
    """The doubtful detection is the aircraft turning hard, and the next scan continues
    the turn: the track keeps what it took (nothing put back) and follows."""
    tracker, track, t = settled(3.0)
    t1, t2 = t + PERIOD, t + 2 * PERIOD
    dy = doubtful_offset(tracker, track, t1)
    p1 = START + VEL * t1 + [dy, 0.0, 0.0]
    step(tracker, t1, [p1])
    p2 = p1 + VEL * PERIOD + [1.5 * dy, 0.0, 0.0]  # the turn goes on
    step(tracker, t2, [p2])
    p3 = p2 + VEL * PERIOD + [1.5 * dy, 0.0, 0.0]  # and on (p2 may be in doubt in turn)
    step(tracker, t2 + PERIOD, [p3])
    assert second_look(tracker).reverted == 0
    assert sorted(tracker.store.where) == [track]
    now = tracker.state(track)["t"]  # p2 taken, not missed; p3 taken or still in doubt
    assert now in (t2, t2 + PERIOD)
    assert np.linalg.norm(state(tracker, track)[0] - (p2 if now == t2 else p3)) < 0.5 * dy


def test_a_deferred_update_puts_no_state_and_a_reachable_one_shows_at_once():
    """Far beyond what an aircraft reaches in a scan, the doubtful update is neither shown
    nor returned as a state (nothing for tracks/) until the next scan; with the reach
    raised above it, the same update is shown and returned at once."""
    for reach, shown_now in ((98.0, False), (1e9, True)):
        tracker, track, t = settled(3.0, max_accel=reach)
        t1 = t + PERIOD
        dy = doubtful_offset(tracker, track, t1)
        out = tracker.step(Unlabelled.of("r1", t1, [det(t1, START + VEL * t1 + [dy, 0.0, 0.0])]))
        ids = [i for block in out.states for i in block.ids]
        moved = np.linalg.norm(shown_at(tracker, track, t1) - (START + VEL * t1))
        assert (track in ids) == shown_now and (moved > 0.5 * dy) == shown_now, reach
        assert second_look(tracker).deferred == (not shown_now)
        t2 = t1 + PERIOD  # the aircraft where it flies: the miss branch, either way
        step(tracker, t2, [START + VEL * t2])
        assert np.linalg.norm(state(tracker, track)[0] - (START + VEL * t2)) < 3 * SIGMA
        assert second_look(tracker).reverted == 1


def test_a_doubt_of_a_track_deleted_meanwhile_is_dropped():
    """A track in doubt that is deleted before the next scan of its dimension with a
    detection (empty scans in between) leaves no doubt behind."""
    tracker, track, t = settled(3.0)
    t1 = t + PERIOD
    dy = doubtful_offset(tracker, track, t1)
    step(tracker, t1, [START + VEL * t1 + [dy, 0.0, 0.0]])
    look = second_look(tracker)
    assert len(look.doubts) == 1
    k = 2
    while track in tracker.store.where:
        tracker.step(Unlabelled.of("r1", t + k * PERIOD, []))
        k += 1
        assert k < 50
    step(tracker, t + k * PERIOD, [START + [9e4, 0.0, 0.0]])  # far from anything
    assert look.doubts == {}


@pytest.mark.parametrize("reach", [98.0, 0.0])
def test_a_confident_detection_beyond_reach_is_weighed_by_the_next_scan(reach):
    """With clutter 100 times sparser, the same far false detection beats a miss by more
    than the margin: no doubt by its score. But it lies beyond an aircraft's reach of the
    track's extrapolation, so its miss branch is kept all the same (its lead counted as a
    doubt's at most), the update is shown at once, and the next scan, the aircraft where
    it flies, puts the track back: one track. Without the reach (0), the jump is kept and
    the aircraft starts a second track."""
    tracker, track, t = settled(4.0, DENSITY / 100, max_accel=reach)
    look = second_look(tracker)
    t1, t2 = t + PERIOD, t + 2 * PERIOD
    dy = doubtful_offset(tracker, track, t1)
    assert dy > 0.5 * 98.0 * PERIOD**2 + 3 * np.sqrt(3) * SIGMA  # beyond reach
    step(tracker, t1, [START + VEL * t1 + [dy, 0.0, 0.0]])
    assert look.deferred == 0  # shown at once
    assert np.linalg.norm(shown_at(tracker, track, t1) - (START + VEL * t1)) > 0.5 * dy
    step(tracker, t2, [START + VEL * t2])
    err = np.linalg.norm(state(tracker, track)[0] - (START + VEL * t2))
    if reach:
        assert look.reverted == 1 and sorted(tracker.store.where) == [track]
        assert err < 3 * SIGMA
    else:
        assert look.reverted == 0 and err > 0.5 * dy
        step(tracker, t2 + PERIOD, [START + VEL * (t2 + PERIOD)])
        assert len(tracker.store.where) == 2  # the aircraft's own new track: a break


def test_a_turn_ending_in_a_missed_scan_keeps_its_track():
    """A traced case at 4 s (the manoeuvres scenario, docs/accuracy.md "Manoeuvres"): a
    4 g turn ends as a scan is missed, and the track takes a false detection 1.8 km off
    with confidence (its wide manoeuvre mode still allows the turn); the aircraft's
    detections at the next scan put it back. Without the second look the aircraft starts
    a second track there and is not held at 2 of its 46 scans."""
    tracker = Tracker.from_config()
    aircraft = manoeuvre_runs.aircraft(tracker, 4.0, 12, "4g-0")
    assert aircraft.breaks == 0 and aircraft.held == aircraft.scans
    assert second_look(tracker).reverted >= 1


def test_a_detection_passed_over_by_a_hair_gets_a_second_chance():
    """The standard-rate aircraft of seed 23 at 10 s scans (an en-route radar's;
    docs/explanation/association.md, "Doubtful updates wait a scan"): a detection of it
    scores a hair below a miss; its branch waits beside the miss and the next scan takes
    it: the aircraft is held at every scan with one id (without the second look: a scan
    not held and a second id)."""
    def run(second_look: float | None) -> tuple[Tracker, object]:
        tracker = Tracker.from_config() if second_look is None else \
            Tracker.from_config(TrackerConfig(second_look=second_look))
        return tracker, manoeuvre_runs.aircraft(tracker, 10.0, 23, "standard-rate-1")

    tracker, aircraft = run(None)
    assert aircraft.breaks == 0 and aircraft.held == aircraft.scans
    look = second_look(tracker)
    assert look.chances >= 1 and look.retaken >= 1
    _, without = run(0.0)
    assert without.breaks == 1 and without.held < without.scans
