"""Track continuation through a running service (docs/protocol.md §3.2, "Track life"):
the new track's key is deleted when it continues a lost one, whose key goes on with the
new state; `status` counts it. Real processes, real Zenoh on loopback."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import zenoh
from test_second_look_service import plots, status
from test_stitcher import AWAY, DENSITY, NEW_VEL, PD, PERIOD, SIGMA, START, VEL

from zenoh_track.wire import unpack

pytestmark = pytest.mark.slow


def test_a_lost_track_found_again_goes_on_under_its_key(service_factory):
    svc, s = service_factory("--clock", "lockstep", "--pd", str(PD), "--clutter-density",
                             str(DENSITY), "--no-display-keys")
    cond, seen = threading.Condition(), []

    def on_tracks(x: zenoh.Sample) -> None:
        with cond:
            body = unpack(x.payload.to_bytes()) if x.kind == zenoh.SampleKind.PUT else None
            seen.append((str(x.key_expr).rsplit("/", 1)[1], body))
            cond.notify_all()

    sub = s.declare_subscriber("track/tracks/*", on_tracks)
    for k in range(15):
        plots(s, k * PERIOD, [START + VEL * k * PERIOD])
    for k in (15, 16):
        plots(s, k * PERIOD, [])
    found = START + VEL * 16 * PERIOD + AWAY
    for k in range(17, 20):
        plots(s, k * PERIOD, [found + NEW_VEL * (k - 17) * PERIOD])
    t = 19 * PERIOD
    with cond:
        assert cond.wait_for(lambda: any(b is None for _, b in seen), 30.0)
        assert cond.wait_for(lambda: any(b and b["t"] == t and k == "r1-1" for k, b in seen),
                             30.0)
    deleted = [k for k, b in seen if b is None]
    assert deleted == ["r1-2"]  # the new track's key, announced like any deletion
    last = [b for k, b in seen if k == "r1-1"][-1]
    assert last["t"] == t and last["updates"] == 15 + 3
    assert np.linalg.norm(np.array(last["pos"]) - (found + NEW_VEL * 2 * PERIOD)) < 4 * SIGMA
    # the new track's puts before its confirmation came under its own key
    assert all(b["t"] < t for k, b in seen if k == "r1-2" and b is not None)
    assert status(s)["tracks_continued"] == 1
    sub.undeclare()
