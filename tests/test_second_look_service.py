"""The second look through a running service (docs/protocol.md §3.2): a doubtful detection
beyond an aircraft's reach puts no `tracks/<id>` for its scan, the next scan's put shows
the branch chosen, and `status` counts both. Real processes, real Zenoh on loopback."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import zenoh
from test_second_look import DENSITY, PD, PERIOD, SIGMA, START, VEL, doubtful_offset, step

from zenoh_track.tracking.plot_association import SensorModels
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import pack, unpack

pytestmark = pytest.mark.slow
BLOCK = zenoh.CongestionControl.BLOCK


def plots(s: zenoh.Session, t: float, positions) -> None:
    s.put("track/plots/r1", pack({"t": t, "sigma": SIGMA, "dets": [
        {"pos": [float(v) for v in p]} for p in positions]}), congestion_control=BLOCK)


def status(s: zenoh.Session) -> dict:
    replies = [r for r in s.get("track/status", timeout=10.0) if r.ok is not None]
    assert replies, "no status reply"
    return unpack(replies[0].ok.payload.to_bytes())


def test_a_far_doubtful_detection_is_not_put_until_the_next_scan(service_factory):
    svc, s = service_factory("--clock", "lockstep", "--pd", str(PD), "--clutter-density",
                             str(DENSITY), "--no-display-keys", "--max-speed", "1000")
    cond, puts = threading.Condition(), []

    def on_tracks(x: zenoh.Sample) -> None:
        if x.kind == zenoh.SampleKind.PUT:
            with cond:
                puts.append(unpack(x.payload.to_bytes()))
                cond.notify_all()

    sub = s.declare_subscriber("track/tracks/*", on_tracks)
    # the same inputs; targets up to 1,000 m/s, as test_second_look.settled (the speed gate)
    mirror = Tracker.from_config(TrackerConfig(sensors=SensorModels(PD, DENSITY), max_speed=1000.0))
    for k in range(15):
        t = k * PERIOD
        plots(s, t, [START + VEL * t])
        step(mirror, t, [START + VEL * t])
    (track,) = mirror.store.where
    t1, t2 = 15 * PERIOD, 16 * PERIOD
    dy = doubtful_offset(mirror, track, t1)  # beats a miss by less than the margin
    plots(s, t1, [START + VEL * t1 + [dy, 0.0, 0.0]])
    plots(s, t2, [START + VEL * t2])
    with cond:
        assert cond.wait_for(lambda: any(abs(p["t"] - t2) < 1e-9 for p in puts), 30.0)
    times = [p["t"] for p in puts]
    assert t1 not in times and times.count(t2) == 1  # held back, then the branch chosen
    last = puts[-1]
    assert np.linalg.norm(np.array(last["pos"]) - (START + VEL * t2)) < 3 * SIGMA
    assert last["updates"] == 16  # 15 scans, then t2: the update held back was dropped
    assert status(s)["second_look"] == {"deferred": 1, "reverted": 1, "chances": 0,
                                        "retaken": 0}
    sub.undeclare()
