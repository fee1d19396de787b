"""Late joiners: a client that comes after the service gets the current picture at once
by query (`get <ns>/frame`, `get <ns>/display/**`: the latest instant published), even
when the picture is paused (lockstep, no input), and track-display fills its table so."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
from conftest import Collector, client_session

from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import decode_frame, unpack


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
