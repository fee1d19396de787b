"""Per-target keys only where someone listens (service/listeners.py), the Zenoh encoding
of every output, and `status` as JSON: the real service process on loopback."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest
import zenoh
from conftest import Collector

from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import MSGPACK_ENCODING as ENCODING
from zenoh_track.wire import unpack

pytestmark = pytest.mark.slow


def status(s: zenoh.Session) -> dict:
    return unpack(next(iter(s.get("track/status", timeout=10))).ok.payload.to_bytes())


def poll(pred, timeout: float = 20.0, every: float = 0.05) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(every)
    return False


class Encodings:
    """Subscribes a key expression and keeps (key, encoding, arrival) of every put."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.got: list[tuple[str, str, float]] = []
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, s: zenoh.Sample) -> None:
        if s.kind == zenoh.SampleKind.PUT:
            self.got.append((str(s.key_expr), str(s.encoding), time.monotonic()))


def test_display_keys_only_for_the_tracks_someone_listens_to(service_factory):
    svc, s = service_factory("--clock", "realtime")
    frames = Encodings(s, "track/frame")
    feed = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm",
                             "--targets", "20",
                             "--duration", "30", "--realtime", "-e", svc.endpoint],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert poll(lambda: status(s)["tracks"] == 20, timeout=30)
        assert poll(lambda: status(s)["frames_published"] > 60, timeout=30)
        # nobody listens to display/ or tracks/: frames only
        st = status(s)
        assert st["display_puts"] == 0 and st["tracks_puts"] == 0
        assert frames.got and {e for _, e, _ in frames.got} == {ENCODING}

        one = Encodings(s, "track/display/swarm-00007")
        asked = time.monotonic()
        assert poll(lambda: len(one.got) >= 45)  # 1.5 s of frames
        first = one.got[0][2] - asked
        assert {k for k, _, _ in one.got} == {"track/display/swarm-00007"}
        assert {e for _, e, _ in one.got} == {ENCODING}
        before = status(s)["display_puts"]
        time.sleep(1.0)
        grown = status(s)["display_puts"] - before
        assert 20 <= grown <= 40, grown  # one track at 30 Hz, not 20

        every = Collector(s, "track/display/**")
        assert every.wait_for(lambda ss: len({k for k, _, _ in ss}) == 20, timeout=10)
        tracks = Encodings(s, "track/tracks/*")
        assert poll(lambda: len({k for k, _, _ in tracks.got}) == 20, timeout=10)
        assert {e for _, e, _ in tracks.got} == {ENCODING}

        for sub in (one.sub, every.sub, tracks.sub):
            sub.undeclare()
        assert poll(lambda: (a := status(s)) and (time.sleep(0.5) or True)
                    and status(s)["display_puts"] == a["display_puts"]
                    and status(s)["tracks_puts"] == a["tracks_puts"], timeout=10)
        print(f"first display/<id> sample {first * 1e3:.0f} ms after subscribing")
    finally:
        stop(feed)


def test_status_as_json_and_encodings_of_replies(service_factory):
    svc, s = service_factory("--clock", "lockstep")
    svc.feed("swarm", "--targets", "3", "--duration", "2")
    reply = next(iter(s.get("track/status?format=json", timeout=10))).ok
    assert str(reply.encoding) == "application/json"
    body = json.loads(reply.payload.to_bytes())
    assert body["tracks"] == 3 and body["meas_accepted"] == 9
    reply = next(iter(s.get("track/status", timeout=10))).ok
    assert str(reply.encoding) == ENCODING and unpack(reply.payload.to_bytes())["tracks"] == 3
    replies = [r.ok for r in s.get("track/tracks/**", timeout=10)]
    assert len(replies) == 3 and {str(r.encoding) for r in replies} == {ENCODING}


def test_lockstep_tracks_of_one_target_every_update(service_factory):
    svc, s = service_factory("--clock", "lockstep")
    one = Collector(s, "track/tracks/swarm-00003")
    svc.feed("swarm", "--targets", "10", "--duration", "4")
    assert one.wait_for(lambda ss: len(ss) >= 5, timeout=20)
    assert {k for k, _, _ in one.samples} == {"track/tracks/swarm-00003"}
    assert [b["updates"] for b in one.bodies()] == [1, 2, 3, 4, 5]
    assert status(s)["tracks_puts"] == 5


def test_batched_states_equal_the_per_target_messages(service_factory):
    import numpy as np

    svc, s = service_factory("--clock", "lockstep")
    batched = Collector(s, "track/states")
    single = Collector(s, "track/tracks/*")
    svc.feed("swarm", "--targets", "30", "--duration", "2")
    assert single.wait_for(lambda ss: len(ss) >= 90, timeout=20)
    assert batched.wait_for(lambda ss: sum(len(b["ids"]) for _, _, b in ss) >= 90, timeout=20)
    rows = {}
    for b in batched.bodies():
        n, k = b["n"], len(b["ids"])
        x = np.frombuffer(b["x"], "<f8").reshape(k, n)
        p = np.frombuffer(b["P"], "<f8").reshape(k, n * n)
        t = np.frombuffer(b["t"], "<f8")
        upd = np.frombuffer(b["updates"], "<f8")
        mu = np.frombuffer(b["mu"], "<f8").reshape(k, len(b["modes"]))
        for i, track_id in enumerate(b["ids"]):
            model = dict(zip(b["modes"], mu[i].tolist(), strict=True))
            rows[(track_id, int(upd[i]))] = (t[i], x[i], p[i], model)
    assert len(rows) == 90
    for body in single.bodies():
        t, x, p, model = rows[(body["id"], body["updates"])]
        assert t == body["t"] and x.tolist() == body["x"] and p.tolist() == body["P"]
        assert model == body["model"]


def test_the_feed_and_the_service_timestamp_what_they_put(service_factory):
    """Zenoh timestamps: a measurement carries its feed's time of publication, a state
    the service's (docs/protocol.md section 6: the realtime clock learns from them)."""
    svc, s = service_factory("--clock", "lockstep")
    got: list[tuple[str, str | None]] = []
    s.declare_subscriber("track/**", zenoh.handlers.Callback(lambda x: got.append(
        (str(x.key_expr), None if x.timestamp is None else str(x.timestamp.get_id()))),
        indirect=False))
    svc.feed("swarm", "--targets", "3", "--duration", "2")
    assert poll(lambda: sum("/tracks/" in k for k, _ in list(got)) >= 9)
    meas = {i for k, i in got if "/meas/" in k}
    states = {i for k, i in got if "/tracks/" in k}
    assert len(meas) == 1 and len(states) == 1 and None not in meas | states
    assert meas != states  # two clocks' stamps: the feed's and the service's


def test_a_realtime_worker_never_waits_for_the_subscribers_answer():
    """The admin-space query goes by the router: with the router stopped, a
    realtime `Listeners` (refresh > 0) returns at once from a look whose read is due, the
    last answer holding; once the router runs again, the next answer is taken. A
    lockstep one (refresh 0) waits for its answer, as a replay must."""
    import os
    import signal

    from test_compose import ROOT, ROUTER

    from zenoh_track.adapter.listeners import ADMIN_TIMEOUT, Listeners
    from zenoh_track.clients import connect
    from zenoh_track.wire import free_port
    from zenoh_track.wire.session import admin_space

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([sys.executable, "-c", ROUTER, str(ROOT / "deploy" /
                                                                 "router.json5"), endpoint],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert router.stdout.readline().strip() == "ready"
    conf = zenoh.Config()  # the service's: a peer of the router, its admin space readable
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    service = zenoh.open(admin_space(conf))
    viewer = connect(endpoint, mode="client", ns="adm")
    realtime = Listeners(service, "adm/tracks", refresh=0.1)
    lockstep = Listeners(service, "adm/display", refresh=0.0)
    try:
        viewer.session.declare_subscriber("adm/tracks/x7", lambda s: None)
        viewer.session.declare_subscriber("adm/display/x7", lambda s: None)
        assert poll(lambda: realtime.look() and realtime.exprs == ("adm/tracks/x7",))
        assert poll(lambda: lockstep.look() and lockstep.exprs == ("adm/display/x7",))
        os.kill(router.pid, signal.SIGSTOP)
        try:
            t0 = time.monotonic()
            assert realtime.look(now=time.monotonic() + 1.0)  # a read due, not answered
            took = time.monotonic() - t0
            assert took < ADMIN_TIMEOUT / 4, took
            assert realtime.wants("x7") and not realtime.wants("x8")  # the last answer
            t0 = time.monotonic()
            lockstep.look()
            waited = time.monotonic() - t0
            assert waited >= ADMIN_TIMEOUT * 0.9, waited
        finally:
            os.kill(router.pid, signal.SIGCONT)
        viewer.session.declare_subscriber("adm/tracks/y1", lambda s: None)
        assert poll(lambda: realtime.look() and realtime.exprs == (
            "adm/tracks/x7", "adm/tracks/y1"))
        print(f"\nrouter stopped: a realtime look {took * 1e3:.2f} ms, a lockstep one "
              f"{waited:.2f} s")
    finally:
        realtime.close()
        lockstep.close()
        viewer.close()
        service.close()
        stop(router)
