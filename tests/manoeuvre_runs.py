"""One run of the `manoeuvres` scenario through an in-process `Tracker`, scored as
`track-eval manoeuvres` scores it (the tests of traced cases)."""

from __future__ import annotations

from zenoh_track.clients.evaluation import manoeuvre_score as ms
from zenoh_track.clients.feeds.manoeuvres import CLASSES, Manoeuvres
from zenoh_track.tracking.batches import Unlabelled
from zenoh_track.tracking.tracker import Tracker
from zenoh_track.wire import Measurement


def fly(tracker: Tracker, period: float, seed: int,
        classes: tuple[str, ...] = CLASSES) -> list[ms.Aircraft]:
    """Every aircraft of run `seed` at `period` (Pd 0.9, 10 clutter a scan, 2 a class),
    scored against what the tracker showed at each scan."""
    sc = Manoeuvres(period, 0.9, 10.0, 2, seed, classes=classes)
    shown = {}
    for s in sc:
        tracker.step(Unlabelled.of(s.sensor, s.t, [
            Measurement(s.sensor, "", s.t, 3, True, tuple(d), (sc.sr, sc.sa, sc.sa),
                        s.sensor_pos, None) for d in s.dets.tolist()]))
        snap = tracker.snapshot(s.t)
        shown[round(s.t, 6)] = {k: snap.pos[i].copy() for i, k in enumerate(snap.ids)
                                if snap.status[i] != "tentative"}
    return ms.score(sc, shown, dict.fromkeys(shown, {}), False)


def aircraft(tracker: Tracker, period: float, seed: int, name: str,
             classes: tuple[str, ...] = CLASSES) -> ms.Aircraft:
    """The one aircraft `name` of `fly`."""
    (found,) = [a for a in fly(tracker, period, seed, classes) if a.name == name]
    return found
