"""The realtime worker's frames within a step (around a pass: `Realtime.apply` and
`Realtime.between`, service/adapter/clocks.py) and the coasting and deletion that go
with them, on a service with a real Zenoh session (the worker's own methods driven in
this thread, as its loop drives them)."""

from __future__ import annotations

import gc
import math
import threading
import time

import zenoh

from zenoh_track.adapter import TrackService
from zenoh_track.adapter.ingest import TRANSIT, ClockMessage, Singles, arrival
from zenoh_track.adapter.senders import FrameSender
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import Keys, free_port, listen_config, pack, peer_config, stamp_ns, stamping


def wait_until(wall: float) -> None:
    while time.time() < wall:  # the condition is the wall clock itself
        time.sleep(min(0.01, max(wall - time.time(), 0.0)))


def test_a_frame_within_a_step_leaves_the_deletion_to_the_steps_end():
    session = zenoh.open(listen_config(f"tcp/127.0.0.1:{free_port()}"))
    try:
        keys = Keys("rt")
        svc = TrackService(session, keys, Tracker.from_config(TrackerConfig(delete_after=0.3)),
                           clock="realtime")
        t = time.time()
        svc._process([Singles.one(keys.meas("r1", "gone"), pack({"t": t, "pos": [0.0, 1.0]}),
                                  time.time())])  # a step, its end included
        assert len(svc.tracker) == 1
        wait_until(t + 0.3 + 2 / 30)  # an instant after the track went stale is due
        svc.clock.between(svc.frames)  # as around a pass: the frame, no deletion
        assert svc.out.latest[0] is not None  # published
        assert svc.clock.unswept is not None and svc.clock.unswept > t + 0.3
        assert len(svc.tracker) == 1
        svc._process([])  # a step's end: the coast and delete of that instant
        assert len(svc.tracker) == 0 and svc.count.tracks_deleted == 1
        assert svc.clock.unswept is None
        svc.close()
    finally:
        session.close()


def test_the_realtime_clock_learns_from_arrival_not_from_when_the_worker_takes_it():
    """A worker busy for 0.3 s while a measurement waits in its channel: the clock's
    offset is t - the arrival (Zenoh's timestamp on arrival), not t - the take."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(stamping(listen_config(ep)))
    feed = zenoh.open(peer_config(ep))
    try:
        keys = Keys("rt")
        svc = TrackService(session, keys, Tracker.from_config(), clock="realtime")
        pub = feed.declare_publisher(keys.meas("r1", "x1"))
        end = time.monotonic() + 10
        while not pub.matching_status.matching and time.monotonic() < end:
            time.sleep(0.01)  # until the feed knows the service's subscriber
        t = time.time()
        pub.put(pack({"t": t, "pos": [0.0, 1.0]}))
        wait_until(t + 0.3)  # the worker busy elsewhere meanwhile
        batch: list = []
        while not batch and time.monotonic() < end:  # it arrived long before: taken now
            batch = svc.ingest.next_batch(0.01)
        taken = time.time()
        svc._process(batch)
        assert svc.count.meas_accepted == 1
        assert taken - t >= 0.3
        assert -0.1 < svc.clock.offset <= 0.0  # t - arrival, not t - taken (<= -0.3)
        svc.close()
    finally:
        feed.close()
        session.close()


def test_arrival_is_the_zenoh_timestamp_within_the_span_it_can_have_arrived_in():
    ep = f"tcp/127.0.0.1:{free_port()}"
    stamped, plain = zenoh.open(stamping(listen_config(ep))), zenoh.open(peer_config(ep))
    try:
        far = stamped.declare_subscriber("a/b", zenoh.handlers.FifoChannel(8))
        pub = plain.declare_publisher("a/b")
        end = time.monotonic() + 10
        while not pub.matching_status.matching and time.monotonic() < end:
            time.sleep(0.01)  # until the other session's subscriber is known here
        near = plain.declare_subscriber("a/b", zenoh.handlers.FifoChannel(8))
        t0 = time.time()
        pub.put(b"x")  # the stamped session stamps it on arrival; the local copy is not
        got = [far.recv(), near.recv()]
        t1 = time.time()
        s = got[0].timestamp.get_time_as_ntp64().as_secs_f64()
        assert t0 - 0.01 <= s <= t1 + 0.01
        assert arrival(got[0], -math.inf, math.inf) == stamp_ns(got[0]) / 1e9
        assert arrival(got[0], s + 1.0, s + 2.0) == s + 1.0 - TRANSIT  # a clock's error
        assert arrival(got[0], s - 2.0, s - 1.0) == s - 1.0  # taken at `now`
        assert got[1].timestamp is None and arrival(got[1], 0.0, 5.0) == 5.0  # no stamp
        v = got[0].timestamp.get_time_as_ntp64()  # older zenoh-python: the 64-bit integer
        bits = (v.as_secs() << 32) | (v.subsec_nanos() << 32) // 1_000_000_000

        class Older:
            class timestamp:  # noqa: N801 (the attribute a sample has)
                @staticmethod
                def get_time_as_ntp64() -> int:
                    return bits

        assert abs(stamp_ns(Older) - stamp_ns(got[0])) <= 1
    finally:
        plain.close()
        stamped.close()


def test_the_frame_sender_puts_every_frame_or_counts_it_replaced_and_the_last_always():
    ep = f"tcp/127.0.0.1:{free_port()}"
    session, viewer = zenoh.open(listen_config(ep)), zenoh.open(peer_config(ep))
    try:
        got: list[bytes] = []
        viewer.declare_subscriber("f", zenoh.handlers.Callback(
            lambda s: got.append(s.payload.to_bytes()), indirect=False))
        pub = session.declare_publisher("f", congestion_control=zenoh.CongestionControl.BLOCK)
        end = time.monotonic() + 10
        while not pub.matching_status.matching and time.monotonic() < end:
            time.sleep(0.01)
        sender = FrameSender(pub)
        bodies = [bytes([i % 256]) * 1_000_000 for i in range(40)]  # faster than they go
        for body in bodies:
            sender.put(body)
        sender.close()  # the frame still waiting goes out first
        end = time.monotonic() + 10
        while len(got) + sender.replaced < len(bodies) and time.monotonic() < end:
            time.sleep(0.01)
        assert len(got) + sender.replaced == len(bodies)
        assert got[-1] == bodies[-1]  # the newest is never the one replaced
        assert got == [b for b in bodies if b in got]  # in order
        assert not sender.thread.is_alive()
    finally:
        viewer.close()
        session.close()


def test_a_clock_message_moves_the_realtime_frames_only_after_the_measurements_before_it():
    session = zenoh.open(listen_config(f"tcp/127.0.0.1:{free_port()}"))
    try:
        keys = Keys("rt")
        svc = TrackService(session, keys, Tracker.from_config(), clock="realtime")
        wall = time.time()
        svc._process([  # one batch: a measurement, then the feed's clock 1 s ahead
            Singles.one(keys.meas("r1", "x1"), pack({"t": wall - 0.5, "pos": [0.0, 1.0]}),
                        wall),
            ClockMessage(keys.clock, pack({"t": wall + 1.0}), wall)])
        t, snap = svc.out.latest[1].t, svc.out.latest[1]
        assert t >= wall + 1.0 - 1 / 30  # the instant the clock message made due
        assert snap.ids == ["x1"]  # shows the measurement received before it
        svc.close()
    finally:
        session.close()


def test_the_worker_freezes_the_long_lived_objects_out_of_the_collectors_scans():
    session = zenoh.open(listen_config(f"tcp/127.0.0.1:{free_port()}"))
    try:
        gc.unfreeze()
        keys = Keys("rt")
        svc = TrackService(session, keys, Tracker.from_config(), clock="realtime").start()
        end = time.monotonic() + 10
        while gc.get_freeze_count() == 0 and time.monotonic() < end:
            time.sleep(0.01)  # an idle worker freezes at once, then every FREEZE_EVERY s
        assert gc.get_freeze_count() > 0
        svc.close()
    finally:
        gc.unfreeze()
        session.close()


def test_batched_scans_taken_together_are_applied_a_pass_each_beyond_the_pass_bound(
        monkeypatch):
    from zenoh_track import defaults
    from zenoh_track.adapter.ingest import LabelledScan
    from zenoh_track.wire import f64_bin

    monkeypatch.setattr(defaults, "PASS_ROWS", 50)
    session = zenoh.open(listen_config(f"tcp/127.0.0.1:{free_port()}"))
    try:
        keys = Keys("rt")
        svc = TrackService(session, keys, Tracker.from_config(), clock="realtime")
        passes: list[int] = []
        rows = svc.calls.rows
        svc.calls.rows = lambda r, *a: (passes.append(len(r)), rows(r, *a))[1]

        def scan(t: float, n: int) -> LabelledScan:
            return LabelledScan(keys.scan("r1"), pack({
                "t": t, "ids": [f"x{i}" for i in range(n)],
                "r": f64_bin([5000.0 + i for i in range(n)]),
                "az": f64_bin([0.001 * i for i in range(n)]), "el": f64_bin([0.01] * n)}),
                time.time())

        t = time.time()
        svc._process([scan(t, 40), scan(t + 0.2, 40), scan(t + 0.4, 5)])
        assert passes == [40, 45]  # 80 > 50 rows: the first scan alone, then the rest
        assert svc.count.meas_accepted == 85 and len(svc.tracker) == 40
        svc.out.close()
    finally:
        session.close()


def test_a_worker_waiting_for_its_sender_publishes_the_frame_falling_due_and_goes_on():
    """After a step the worker waits for its `tracks/` sender, up to `DRAIN` s; a
    subscriber that stalls holds the sender up: the display instant falling due meanwhile
    goes out at once, and the worker does not wait beyond `DRAIN`."""
    from zenoh_track.adapter.schedule import DRAIN

    ep = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(listen_config(ep))
    viewer = zenoh.open(peer_config(ep))
    release = threading.Event()
    try:
        keys = Keys("rt")
        viewer.declare_subscriber(keys.tracks("**"), zenoh.handlers.Callback(
            lambda _: release.wait(10), indirect=False))
        svc = TrackService(session, keys, Tracker.from_config(), clock="realtime")
        probe = session.declare_publisher(keys.tracks("x"))
        end = time.monotonic() + 10
        while not probe.matching_status.matching and time.monotonic() < end:
            time.sleep(0.01)  # the service knows the stalled subscriber
        probe.undeclare()
        svc._process([Singles.one(keys.meas("r1", "a"), pack({"t": time.time(),
                                                               "pos": [0.0, 1.0]}),
                                  time.time())])  # the clock has its offset
        sender = svc.out.track_sender
        held = [zenoh.KeyExpr(keys.tracks(f"t{i}")) for i in range(100)]
        for _ in range(5):  # more than Zenoh's queues and the socket hold
            sender.put(held, [b"x" * 60_000] * len(held))
        published = svc.count.frames_published
        t0 = time.monotonic()
        svc._drain()
        assert svc.count.frames_published > published
        assert time.monotonic() - t0 < DRAIN + 0.5 and not sender.idle()
        release.set()
        assert sender.drain(30)
        svc.close()
    finally:
        release.set()
        viewer.close()
        session.close()
