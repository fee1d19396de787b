"""Track continuation (tracking.stitcher): a track confirmed where a lost one could have
gone keeps the lost one's id; targets side by side, and a new track two lost ones could
continue, are never joined. The default filter, unlabelled 3-D detections every 4 s."""

from __future__ import annotations

import manoeuvre_runs
import numpy as np
from reference.record import Outcome

from zenoh_track.tracking.batches import StepOutcome, Unlabelled
from zenoh_track.tracking.plot_association import SensorModels
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import Measurement

SIGMA, PERIOD, PD = 50.0, 4.0, 0.9
DENSITY = 1e-10  # false detections per m^3: a far detection scores below a miss
START = np.array([30_000.0, 5_000.0, 8_000.0])
VEL = np.array([0.0, 200.0, 0.0])
AWAY = np.array([3_000.0, -1_000.0, 0.0])  # where the aircraft is found after the turn
NEW_VEL = np.array([200.0, 0.0, 0.0])


def scan(tracker: Tracker, k: int, positions) -> StepOutcome:
    t = k * PERIOD
    dets = [Outcome(Measurement("r1", "", t, 3, False, tuple(float(v) for v in p),
                                (SIGMA,) * 3, (0.0, 0.0, 0.0), None)).meas for p in positions]
    return tracker.step(Unlabelled.of("r1", t, dets))


def flown(reach: float | None = None, other: bool = False) -> tuple[Tracker, list[StepOutcome]]:
    """An aircraft tracked 15 scans on a straight leg, unseen at 2 scans (a hard turn),
    then found 3 km off on a new heading for 5 scans (`other`: a second aircraft lost
    the same way 2 km beside it, found nowhere)."""
    cfg = TrackerConfig(sensors=SensorModels(PD, DENSITY))
    if reach is not None:
        cfg = TrackerConfig(sensors=SensorModels(PD, DENSITY), stitch_reach=reach)
    tracker = Tracker.from_config(cfg)
    side = np.array([2_000.0, 0.0, 0.0])
    for k in range(15):
        p = START + VEL * k * PERIOD
        scan(tracker, k, [p, p + side] if other else [p])
    outs = [scan(tracker, k, []) for k in (15, 16)]
    found = START + VEL * 16 * PERIOD + AWAY
    outs += [scan(tracker, k, [found + NEW_VEL * (k - 17) * PERIOD]) for k in range(17, 22)]
    return tracker, outs


def test_a_track_found_again_on_a_new_heading_keeps_its_id():
    before, _ = flown(reach=0.0)
    assert set(before.store.where) == {"r1-2"}  # the lost track deleted, a new id
    tracker, outs = flown()
    (track,) = tracker.store.where  # one track: the old id goes on
    assert track == "r1-1"
    arrays, row = tracker.store.where[track]
    found = START + VEL * 16 * PERIOD + AWAY + NEW_VEL * 4 * PERIOD
    assert np.linalg.norm(arrays.x[row, :3] - found) < 4 * SIGMA
    assert arrays.updates[row] == 15 + 5 and arrays.t_first[row] == 0.0
    assert tracker.counts()["continued"] == 1
    # the scan that confirmed the new track: its id announced deleted, its state renamed
    joined = outs[4]  # scan 19: detected at 3 of 17, 18, 19
    assert joined.deleted == ["r1-2"]
    assert [i for s in joined.states for i in s.ids] == ["r1-1"]
    assert [int(u) for s in joined.states for u in s.updates] == [15 + 3]
    assert all(not o.deleted for o in outs if o is not joined)


def test_two_lost_tracks_that_could_both_go_on_are_not_joined():
    tracker, _ = flown(other=True)
    assert tracker.counts()["continued"] == 0
    assert set(tracker.store.where) == {"r1-3"}  # both lost tracks deleted meanwhile


def test_a_target_beside_a_tracked_one_starts_its_own_track():
    """A second aircraft 1 km beside a tracked one, seen from scan 10: the tracked one is
    detected at every scan, so the new track is another aircraft, not a continuation."""
    tracker = Tracker.from_config(TrackerConfig(sensors=SensorModels(PD, DENSITY)))
    for k in range(20):
        p = START + VEL * k * PERIOD
        scan(tracker, k, [p, p + [1_000.0, 0.0, 0.0]] if k >= 10 else [p])
    assert tracker.counts()["continued"] == 0 and len(tracker.store) == 2


def test_a_4g_aircraft_at_10_s_keeps_one_track():
    """A 4 g aircraft of seed 11 at 10 s scans (a long-range radar's; docs/accuracy.md,
    "Beyond 5 s"): with the widest mode's noise bounded (`defaults.IMM_WIDE_DV`) the one
    track holds it through the turn, with or without continuation; unbounded, that
    mode's gate grows kilometres wide over 10 s, the track loses the aircraft and a second
    id takes it (which continuation would give the lost track's id)."""
    import dataclasses

    def breaks(reach: float | None, bounded: bool = True) -> int:
        config = TrackerConfig() if reach is None else TrackerConfig(stitch_reach=reach)
        built = config.filter.build()
        if not bounded:
            built = dataclasses.replace(built, updater=dataclasses.replace(built.updater,
                                                                           dv_cap=0.0))
        tracker = Tracker.from_config(config, filter=built)
        return manoeuvre_runs.aircraft(tracker, 10.0, 11, "4g-1").breaks

    assert breaks(0.0) == 0 and breaks(None) == 0
    assert breaks(0.0, bounded=False) == 1
