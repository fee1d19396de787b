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


class Deployment:
    """A router, the service's session (a peer of it) and a viewer's (a client of it)."""

    def __init__(self) -> None:
        from test_compose import ROOT, ROUTER

        from zenoh_track.clients import connect
        from zenoh_track.wire import free_port

        endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.router = subprocess.Popen(
            [sys.executable, "-c", ROUTER, str(ROOT / "deploy" / "router.json5"), endpoint],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.router.stdout.readline().strip() == "ready"
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        self.service = zenoh.open(conf)
        self.viewer = connect(endpoint, mode="client", ns="adm")

    def close(self) -> None:
        self.viewer.close()
        self.service.close()
        stop(self.router)


IDS = [f"swarm-{i:05d}" for i in range(40)] + ["interceptor-1", "interceptor-2", "x7", "x70",
                                                 "x8"]


def intersected(exprs: list[str], ids: list[str]) -> list[int]:
    """The indices of the ids whose display/ key some expression intersects (the truth)."""
    kes = [zenoh.KeyExpr(e) for e in exprs]
    return [i for i, t in enumerate(ids) if any(
        k.intersects(zenoh.KeyExpr(f"adm/display/{t}")) for k in kes)]


def test_the_tracks_wanted_are_those_a_subscriber_intersects():
    """Zenoh's matching status, asked prefix by prefix: each subscriber as it comes (a
    newcomer under a prefix ruled out is seen at the next look), each one's leaving once
    the ids wanted are probed again, every key at once for `**`; never an id missed, also when
    the probes run out."""
    from zenoh_track.adapter.listeners import PROBES, Listeners

    dep = Deployment()
    listeners = Listeners(dep.service, "adm/display", refresh=0.0, reset=0.5)
    subs: dict[str, zenoh.Subscriber] = {}
    seen: list[str] = []

    def shows(exprs: list[str]) -> bool:
        listeners.look()
        got = listeners.select(list(IDS))
        got = list(range(len(IDS))) if got is None else got.tolist()
        seen[:] = [IDS[i] for i in got]
        return got == intersected(exprs, IDS)

    try:
        assert shows([]) and listeners.none
        steps = [["adm/display/interceptor-$*"],
                 ["adm/display/interceptor-$*", "adm/display/x7"],
                 ["adm/display/x7"],
                 ["adm/display/x7", "adm/display/$*0"],
                 ["adm/display/x7", "adm/display/$*0", "adm/display/**"],
                 ["adm/display/x7"]]
        for exprs in steps:
            for e in set(subs) - set(exprs):
                subs.pop(e).undeclare()
            for e in set(exprs) - set(subs):
                subs[e] = dep.viewer.session.declare_subscriber(e, lambda s: None)
            every = "adm/display/**" in exprs
            assert poll(lambda exprs=exprs, every=every: shows(exprs) and
                        listeners.everything == every, timeout=10), (exprs, seen)
            assert len(listeners.held) <= PROBES
        # matched down to the ids one by one: the probes run out, the ids left undecided
        # are wanted
        many = [f"t{i:04d}" for i in range(10 * PROBES)]
        subs["odd"] = dep.viewer.session.declare_subscriber("adm/display/t$*5$*",
                                                            lambda s: None)
        truth = intersected(["adm/display/x7", "adm/display/t$*5$*"], many)
        assert poll(lambda: listeners.look() and set(truth) <= set(
            listeners.select(many).tolist()), timeout=10)
        got = listeners.select(many).tolist()
        assert len(listeners.held) <= PROBES and len(truth) < len(got) < len(many)
    finally:
        listeners.close()
        dep.close()


def test_a_recheck_asks_again_about_the_wanted_ids_only():
    """The periodic recheck probes the ids that go out, not the ones ruled out: those
    keep their verdict (a newcomer under them is seen by a held probe), and a subscriber
    who left stops costing puts all the same."""
    from zenoh_track.adapter.listeners import Listeners

    dep = Deployment()
    listeners = Listeners(dep.service, "adm/tracks", refresh=0.0, reset=0.5)
    ids = [f"swarm-{i:05d}" for i in range(2000)]
    subs = [dep.viewer.session.declare_subscriber(e, lambda s: None)
            for e in ("adm/tracks/swarm-$*00", "adm/tracks/swarm-$*50")]
    try:
        truth = intersected(["adm/display/swarm-$*00", "adm/display/swarm-$*50"], ids)
        assert poll(lambda: listeners.look() and listeners.select(ids).tolist() == truth)
        ruled_out = {i for i, got in listeners.memo.items() if not got}
        assert len(ruled_out) == len(ids) - len(truth)
        subs.pop().undeclare()  # the $*50 subscriber leaves: no probe sees it
        due = listeners.started + listeners.reset
        assert poll(lambda: time.monotonic() >= due)
        listeners.look()  # the recheck, before any select
        assert listeners.started >= due
        assert ruled_out <= {i for i, got in listeners.memo.items() if not got}
        left = intersected(["adm/display/swarm-$*00"], ids)
        assert poll(lambda: listeners.look() and listeners.select(ids).tolist() == left)
    finally:
        for sub in subs:
            sub.undeclare()
        listeners.close()
        dep.close()


def test_subscribers_coming_and_going_never_wedge_the_session():
    """Two key spaces looked at as fast as a worker can while a viewer declares and
    undeclares subscribers in them without pause: every look returns, and the session
    still answers a query at the end."""
    import threading

    from zenoh_track.adapter.listeners import Listeners

    dep = Deployment()
    spaces = [Listeners(dep.service, f"adm/{s}", refresh=0.0) for s in ("display", "tracks")]
    ids = [f"x{i}" for i in range(50)]
    looks, last, done = [0], [time.monotonic()], threading.Event()

    def worker() -> None:
        while not done.is_set():
            for space in spaces:
                if space.look():
                    space.select(ids)
            looks[0] += 1
            last[0] = time.monotonic()

    def churn() -> None:
        i = 0
        while not done.is_set():
            sub = dep.viewer.session.declare_subscriber(
                f"adm/{('display', 'tracks')[i % 2]}/x{i % 50}", lambda s: None)
            time.sleep(0.002)
            sub.undeclare()
            i += 1

    queryable = dep.service.declare_queryable("adm/ping", lambda q: q.reply("adm/ping", b"1"))
    threads = [threading.Thread(target=f, daemon=True) for f in (worker, churn)]
    for t in threads:
        t.start()
    try:
        end = time.monotonic() + 8.0
        stalled = 0.0
        while time.monotonic() < end and stalled < 4.0:
            time.sleep(0.2)
            stalled = time.monotonic() - last[0]
        assert stalled < 4.0, f"no look returned for {stalled:.1f} s after {looks[0]} looks"
        replies = list(dep.viewer.session.get("adm/ping", timeout=5))
        assert [r.ok.payload.to_bytes() for r in replies] == [b"1"]
    finally:
        done.set()
        for t in threads:
            t.join(timeout=5)
        queryable.undeclare()
        for space in spaces:
            space.close()
        dep.close()
