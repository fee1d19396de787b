"""The realtime worker's frames within a step (around a pass: `TrackService._flush`) and
the coasting and deletion that go with them, on a service with a real Zenoh session (the
worker's own methods driven in this thread, as its loop drives them)."""

from __future__ import annotations

import time

import zenoh

from service.node import TrackService
from service.tracking.tracker import Tracker, TrackerConfig
from service.wire import Keys, free_port, listen_config, pack


def wait_until(wall: float) -> None:
    while time.time() < wall:  # the condition is the wall clock itself
        time.sleep(min(0.01, max(wall - time.time(), 0.0)))


def test_a_frame_within_a_step_leaves_the_deletion_to_the_steps_end():
    session = zenoh.open(listen_config(f"tcp/127.0.0.1:{free_port()}"))
    try:
        keys = Keys("rt")
        svc = TrackService(session, keys, Tracker(TrackerConfig(delete_after=0.3)),
                           clock="realtime")
        t = time.time()
        svc._process([("meas", keys.meas("r1", "gone"), pack({"t": t, "pos": [0.0, 1.0]}),
                       time.time())])
        svc._tick()
        assert len(svc.tracker) == 1
        wait_until(t + 0.3 + 2 / 30)  # an instant after the track went stale is due
        svc._frame_between()  # as around a pass: the frame, no deletion
        assert svc.out.latest[0] is not None  # published
        assert svc.unswept is not None and svc.unswept > t + 0.3
        assert len(svc.tracker) == 1
        svc._tick()  # the step's end: the coast and delete of that instant
        assert len(svc.tracker) == 0 and svc.count.tracks_deleted == 1
        assert svc.unswept is None
        svc.close()
    finally:
        session.close()
