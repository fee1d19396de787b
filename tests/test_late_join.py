"""Late joiners: a client that comes after the service gets the current picture at once
by query (`get <ns>/frame`, `get <ns>/display/**`: the latest instant published), even
when the picture is paused (lockstep, no input), and track-display fills its table so."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zenoh
from conftest import Collector, client_session
from test_compose import ROOT, ROUTER

from zenoh_track.adapter.encode import pack_frame
from zenoh_track.clients import connect
from zenoh_track.clients.lib.picture import JOIN_WAIT
from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import Keys, decode_frame, free_port, pack, unpack


@pytest.mark.slow
def test_a_late_joiner_gets_the_latest_instant_at_once(service_factory):
    svc, early = service_factory("--clock", "lockstep", ns="late")
    frames = Collector(early, svc.keys.frame)
    display = Collector(early, svc.keys.space("display"))
    svc.feed("swarm", "--targets", "8", "--duration", "3")
    names = {f"swarm-{i:05d}" for i in range(8)}
    last_t = 3 + 29 / 30
    assert frames.wait_for(lambda s: s and s[-1][2]["t"] >= last_t - 1e-9, 30)
    last = frames.bodies()[-1]

    late = client_session(svc.endpoint)  # the picture is paused: no frame will come
    try:
        t0 = time.monotonic()
        got = [unpack(r.ok.payload.to_bytes()) for r in late.get(svc.keys.frame, timeout=10)]
        t_frame = time.monotonic() - t0
        assert len(got) == 1 and got[0] == last  # the very frame published last
        t0 = time.monotonic()
        states = {str(r.ok.key_expr).rsplit("/", 1)[1]: unpack(r.ok.payload.to_bytes())
                  for r in late.get(svc.keys.space("display"), timeout=10)}
        t_display = time.monotonic() - t0
        assert set(states) == names
        latest = {k.rsplit("/", 1)[1]: b for k, kind, b in display.samples if kind == "PUT"}
        assert states == latest and all(b["t"] == last["t"] for b in states.values())
        assert {r["id"] for r in decode_frame(last)} == names
        one = [r for r in late.get(svc.keys.display("swarm-00003"), timeout=10)]
        assert [str(r.ok.key_expr) for r in one] == [svc.keys.display("swarm-00003")]
        print(f"\nlate joiner, paused lockstep picture of 8 tracks: get frame {t_frame * 1e3:.1f} "
              f"ms, get display/** {t_display * 1e3:.1f} ms")
    finally:
        late.close()

    # track-display started now shows every track of the paused picture
    shown = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.display.display", "-e",
                              svc.endpoint,
                              "--ns", svc.ns, "--hz", "10"], stdout=subprocess.PIPE,
                             text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        deadline = time.monotonic() + 20
        screen = ""
        while time.monotonic() < deadline and "tracks=8" not in screen:
            screen = shown.stdout.readline()
    finally:
        stop(shown)
    assert "tracks=8" in screen, screen


class Instance:
    """A track-service instance as its clients see it, on a real Zenoh session: its
    liveliness token, a frame of `ids` at 30 Hz on `<ns>/frame`, and the `frame`
    queryable, which answers with its latest frame or, `answers` False, holds every query
    unanswered (a reply lost on the way)."""

    def __init__(self, endpoint: str, ns: str, name: str, ids: list[str],
                 answers: bool) -> None:
        self.keys, self.name, self.ids = Keys(ns), name, ids
        self.client = connect(endpoint, mode="client", ns=ns)
        self.session = self.client.session
        self.latest, self.held, self.stop = b"", [], threading.Event()
        self.token = self.session.liveliness().declare_token(self.keys.alive(name))
        self.queryable = self.session.declare_queryable(
            self.keys.frame, self._answer if answers else self.held.append)
        self.put(0)  # a frame before anyone asks
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def put(self, n: int) -> None:
        k = len(self.ids)
        self.latest = pack_frame(n / 30.0, pack(self.ids), np.zeros((k, 3)), np.zeros((k, 3)),
                                 np.ones(k), np.ones(k, np.uint8), self.name)
        self.session.put(self.keys.frame, self.latest)

    def _answer(self, query: zenoh.Query) -> None:
        query.reply(self.keys.frame, self.latest)

    def _run(self) -> None:
        n = 1
        while not self.stop.wait(1 / 30.0):
            self.put(n)
            n += 1

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.held.clear()
        self.client.close()


@pytest.mark.slow
def test_a_late_joiner_has_an_instance_whose_reply_is_lost_from_its_frames():
    """One instance answers the joiner's query, the other holds it unanswered: the first
    picture still holds both instances' tracks (the silent one's from its next frame on
    `frame`), without waiting out the query."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([sys.executable, "-c", ROUTER, str(ROOT / "deploy" /
                                                                 "router.json5"), endpoint],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert router.stdout.readline().strip() == "ready"
    ns = f"lost{free_port()}"
    a, b = ([f"a-{i}" for i in range(5)], [f"b-{i}" for i in range(3)])
    answering = Instance(endpoint, ns, "shard-a", a, answers=True)
    silent = Instance(endpoint, ns, "shard-b", b, answers=False)
    client = connect(endpoint, mode="client", ns=ns)
    try:
        client.wait_for_service(2)
        t0 = time.monotonic()
        first: list = []
        pic = client.picture(on_frame=first.append)
        took = time.monotonic() - t0
        assert silent.held  # the query reached it and stays unanswered
        assert first and sorted(first[0].instances) == ["shard-a", "shard-b"]
        assert sorted(first[0].id_list) == sorted(a + b)
        assert took < JOIN_WAIT / 2, took  # the silent instance's frames ended the wait
        pic.close()
        print(f"\nlate joiner, one instance's reply lost: first picture of both after "
              f"{took * 1e3:.0f} ms")
    finally:
        client.close()
        answering.close()
        silent.close()
        stop(router)
