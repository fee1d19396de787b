"""The worker's batches of single messages (service/adapter/ingest.py `Ingest.next_batch`,
worker.py `_take_singles`): measurements taken from Zenoh's channel straight into a step keep their
order against queries, `seq` gaps are counted as message by message, bad keys are
reported once each and their chunks remembered, on the real service process."""

from __future__ import annotations

import time

import pytest
import zenoh
from conftest import Collector

from zenoh_track.wire import pack, unpack

pytestmark = pytest.mark.slow
BLOCK = zenoh.CongestionControl.BLOCK


def status(s: zenoh.Session) -> dict:
    return unpack(next(iter(s.get("track/status", timeout=10))).ok.payload.to_bytes())


def poll(pred, timeout: float = 30.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.05)
    return False


def message(i: int, t: float, seq: int | None) -> bytes:
    m = {"t": t, "r": 5000.0 + 10 * i, "az": 0.001 * i, "el": 0.05, "sr": 10.0,
         "saz": 0.002, "sel": 0.002}
    return pack(m if seq is None else m | {"seq": seq})


def test_bursts_keep_order_count_gaps_and_report_bad_keys(service_factory):
    _, s = service_factory("--clock", "realtime")
    errors = Collector(s, "track/errors/**")
    pub = s.declare_publisher("track/meas/**")
    assert poll(lambda: pub.matching_status.matching)
    # one sensor's numbered burst with gaps, a lower seq in between, then a second sensor
    # unnumbered, and bad keys in the middle: each as if taken alone
    seqs = [*range(0, 100), *range(150, 200), 120, *range(200, 250)]  # 50 lost
    t0 = time.time()
    sent = 0
    for j, q in enumerate(seqs):
        s.put(f"track/meas/r1/x{j}", message(j, t0, q), congestion_control=BLOCK)
        sent += 1
        if j == 120:
            s.put("track/meas/onlysensor", message(j, t0, None), congestion_control=BLOCK)
            s.put("track/meas/r1/a/b", message(j, t0, None), congestion_control=BLOCK)
    for j in range(40):
        s.put(f"track/meas/r2/y{j}", message(j, t0, None), congestion_control=BLOCK)
    # a query right behind the burst: answered once every measurement before it is applied
    replies = [r.ok for r in s.get("track/tracks/**", timeout=20) if r.ok is not None]
    ids = {str(r.key_expr).rsplit("/", 1)[1] for r in replies}
    assert ids == {f"x{j}" for j in range(len(seqs))} | {f"y{j}" for j in range(40)}
    st = status(s)
    assert st["meas_accepted"] == len(seqs) + 40 and st["meas_rejected"] == 2
    assert st["meas_lost"] == 50
    assert errors.wait_for(lambda got: len(got) == 2, timeout=10)
    assert sorted(b["key"] for b in errors.bodies()) == ["track/meas/onlysensor",
                                                         "track/meas/r1/a/b"]
    # the same keys again (remembered chunks), a second later, seq going on after a gap
    t1 = t0 + 1.0
    for j in range(len(seqs)):
        s.put(f"track/meas/r1/x{j}", message(j, t1, 260 + j), congestion_control=BLOCK)
    s.put("track/meas/onlysensor", message(0, t1, None), congestion_control=BLOCK)
    replies = [r.ok for r in s.get("track/tracks/**", timeout=20) if r.ok is not None]
    times = {str(r.key_expr).rsplit("/", 1)[1]: unpack(r.payload.to_bytes())["t"]
             for r in replies}
    assert all(times[f"x{j}"] == pytest.approx(t1) for j in range(len(seqs)))
    st = status(s)
    assert st["meas_accepted"] == 2 * len(seqs) + 40 and st["meas_rejected"] == 3
    assert st["meas_lost"] == 50 + 10  # 250..259


def test_a_burst_behind_a_query_comes_in_batches_of_at_most_max_batch_in_order():
    """2,500 messages moved into the inbox as one run by a query behind them: the worker
    takes them 1,024 messages at a time, in order, and the query after the last."""
    from zenoh_track.adapter import TrackService
    from zenoh_track.adapter.ingest import MAX_BATCH, Query, Singles, size
    from zenoh_track.tracking.tracker import Tracker
    from zenoh_track.wire import Keys, free_port, listen_config, peer_config

    ep = f"tcp/127.0.0.1:{free_port()}"
    session, feed = zenoh.open(listen_config(ep)), zenoh.open(peer_config(ep))
    svc = None
    try:
        keys = Keys("mb")
        # the worker not started
        svc = TrackService(session, keys, Tracker.from_config(), clock="lockstep")
        pub = feed.declare_publisher(keys.meas("r1", "probe"))
        assert poll(lambda: pub.matching_status.matching)
        n = 2500
        for i in range(n):
            feed.put(keys.meas("r1", f"x{i}"), message(i, 1.0, i), congestion_control=BLOCK)
        replies = feed.get(keys.status, timeout=10)  # its callback moves the burst first
        assert poll(lambda: svc.ingest.waiting() == 2)  # the run and the query
        batches = []
        while sum(map(size, (it for b in batches for it in b))) < n + 1:
            batches.append(svc.ingest.next_batch(0.1))
        assert [sum(map(size, b)) for b in batches] == [MAX_BATCH, MAX_BATCH, n - 2 * MAX_BATCH + 1]
        items = [it for b in batches for it in b]
        assert isinstance(items[-1], Query)
        keys_taken = [k for it in items[:-1] for k in it.keys if isinstance(it, Singles)]
        assert keys_taken == [keys.meas("r1", f"x{i}") for i in range(n)]
        svc.queries.answer(items[-1])
        assert unpack(next(iter(replies)).ok.payload.to_bytes())["queue"] == 0
    finally:
        if svc is not None:
            svc.close()
        feed.close()
        session.close()
