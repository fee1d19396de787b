"""The realtime service's `tracks/` sender (service/adapter/senders.py, `TrackSender`):
every state and deletion handed over reaches a subscriber in order, what waits goes out
on close, and a slow subscriber makes the worker wait (BLOCK) instead of a message being
dropped. On real Zenoh sessions on loopback."""

from __future__ import annotations

import threading
import time

import zenoh

from zenoh_track.adapter.publish import MSGPACK
from zenoh_track.adapter.senders import TrackSender
from zenoh_track.wire import free_port, listen_config, peer_config


def sessions() -> tuple[zenoh.Session, zenoh.Session]:
    ep = f"tcp/127.0.0.1:{free_port()}"
    return zenoh.open(listen_config(ep)), zenoh.open(peer_config(ep))


def wait_matching(session: zenoh.Session, key: str) -> None:
    probe = session.declare_publisher(key)
    end = time.monotonic() + 10
    while not probe.matching_status.matching and time.monotonic() < end:
        time.sleep(0.01)
    probe.undeclare()


def stalled_subscriber(service: zenoh.Session, viewer: zenoh.Session
                       ) -> tuple[list[int], threading.Event]:
    """A subscriber of `s/tracks/**` on `viewer` that stalls until the event is set: the
    count of what it received and the event."""
    count = [0]
    release = threading.Event()

    def slow(_: zenoh.Sample) -> None:
        release.wait(10)
        count[0] += 1

    viewer.declare_subscriber("s/tracks/**", zenoh.handlers.Callback(slow, indirect=False))
    wait_matching(service, "s/tracks/**")
    return count, release


def test_states_and_deletions_arrive_in_the_order_handed_over_and_close_puts_the_rest():
    service, viewer = sessions()
    try:
        got: list[tuple[str, str, bytes]] = []
        viewer.declare_subscriber("s/tracks/**", zenoh.handlers.Callback(
            lambda s: got.append((str(s.key_expr), str(s.kind), s.payload.to_bytes())),
            indirect=False))
        wait_matching(service, "s/tracks/**")
        sender = TrackSender(service, MSGPACK)
        keys = [zenoh.KeyExpr(f"s/tracks/t{i}") for i in range(600)]  # > one slice
        want: list[tuple[str, str, bytes]] = []
        for round_ in range(3):
            bodies = [f"{round_}:{i}".encode() for i in range(len(keys))]
            sender.put(keys, bodies)
            want += [(str(k), str(zenoh.SampleKind.PUT), b)
                     for k, b in zip(keys, bodies, strict=True)]
        sender.delete(keys[:10])  # after the states handed over before
        want += [(str(k), str(zenoh.SampleKind.DELETE), b"") for k in keys[:10]]
        sender.close()  # everything waiting goes out first
        assert not sender.thread.is_alive()
        end = time.monotonic() + 10
        while len(got) < len(want) and time.monotonic() < end:
            time.sleep(0.01)
        assert got == want
        assert sender.idle() and sender.waiting == 0
    finally:
        viewer.close()
        service.close()


def test_a_slow_subscriber_makes_the_hand_over_wait_and_nothing_is_dropped():
    service, viewer = sessions()
    release = threading.Event()
    try:
        count, release = stalled_subscriber(service, viewer)
        sender = TrackSender(service, MSGPACK, limit=100)
        keys = [zenoh.KeyExpr(f"s/tracks/t{i}") for i in range(100)]
        body = b"x" * 60_000  # Zenoh's queues fill within a few of these
        done = threading.Event()

        def hand_over() -> None:
            for _ in range(5):
                sender.put(keys, [body] * len(keys))
            done.set()

        worker = threading.Thread(target=hand_over)
        worker.start()
        assert not done.wait(1.0)  # the worker waits: more than `limit` are held
        assert sender.waiting >= sender.limit
        release.set()
        worker.join(timeout=30)
        assert done.is_set()
        sender.close(timeout=30)
        end = time.monotonic() + 30
        while count[0] < 500 and time.monotonic() < end:
            time.sleep(0.01)
        assert count[0] == 500
    finally:
        release.set()
        viewer.close()
        service.close()


def test_drain_returns_once_everything_is_put_and_gives_up_at_its_timeout():
    service, viewer = sessions()
    release = threading.Event()
    try:
        count, release = stalled_subscriber(service, viewer)
        sender = TrackSender(service, MSGPACK)
        keys = [zenoh.KeyExpr(f"s/tracks/t{i}") for i in range(100)]
        for _ in range(5):  # more than Zenoh's queues and the socket hold
            sender.put(keys, [b"x" * 60_000] * len(keys))
        t0 = time.monotonic()
        assert not sender.drain(0.3)  # the subscriber stalls: the worker goes on after
        assert time.monotonic() - t0 >= 0.3 and not sender.idle()  # the timeout
        release.set()
        assert sender.drain(30)
        assert sender.idle() and sender.waiting == 0  # every put made
        end = time.monotonic() + 30
        while count[0] < 5 * len(keys) and time.monotonic() < end:
            time.sleep(0.01)
        assert count[0] == 5 * len(keys)
        sender.close()
    finally:
        release.set()
        viewer.close()
        service.close()
