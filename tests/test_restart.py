"""Service restart with the picture kept (`--state PATH`), with real processes: a service
stopped by SIGTERM and started again has every track back before any new measurement,
the gap predicted (age, sigma, coasting); a corrupt state file is refused in one line and
the service starts empty. The restore time is printed (pytest -s; docs/operations.md)."""

from __future__ import annotations

import subprocess
import sys
import time
import uuid

import numpy as np
import pytest
import zenoh
from conftest import ServiceProc, client_session
from routers import DEPLOY, ENV, RouterProc, Stamped, client_conf

from zenoh_track.clients import ServiceProcess
from zenoh_track.wire import Keys, decode_frame, free_port, unpack, wait_for_tracker

TARGETS = 20


def get_all(session: zenoh.Session, selector: str) -> list[dict]:
    return [unpack(r.ok.payload.to_bytes()) for r in session.get(selector, timeout=10)]


def service(endpoint: str, keys: Keys, state, *extra: str) -> ServiceProcess:
    """A service of deploy/shard-a.json5, a client of the router at `endpoint`."""
    return ServiceProcess("-c", str(DEPLOY / "shard-a.json5"), "--state", str(state), *extra,
                          ns=keys.ns, clock=None, connect=endpoint)


def frames_with(frames: Stamped, names: set[str], since: float) -> list:
    return [(t, decode_frame(b)) for t, _, k, b in frames.snapshot()
            if k == "PUT" and t >= since and {r["id"] for r in decode_frame(b)} >= names]


@pytest.mark.slow
def test_restart_brings_every_track_back_before_any_measurement(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys(f"rs{uuid.uuid4().hex[:8]}")
    state = tmp_path / "tracks.state"
    names = {f"swarm-{i:05d}" for i in range(TARGETS)}
    router = RouterProc(DEPLOY / "router.json5", endpoint)
    router.start()
    svc = None
    session = None
    try:
        svc = service(endpoint, keys, state)
        session = zenoh.open(client_conf(DEPLOY / "client.json5", endpoint))
        frames = Stamped(session, keys.frame)
        display = Stamped(session, keys.space("display"))
        assert wait_for_tracker(session, keys, 1, timeout=30)
        subprocess.run([sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm",
                       "--targets",
                        str(TARGETS), "--duration", "3", "--realtime", "-c",
                        str(DEPLOY / "client.json5"), "-e", endpoint, "--ns", keys.ns],
                       capture_output=True, timeout=60, check=True, env=ENV)
        before = {b["id"]: b for b in get_all(session, keys.space("tracks"))}
        assert set(before) == names
        err = svc.stop()  # SIGTERM: the last checkpoint is written on the way out
        assert "Traceback" not in err and state.is_file(), err
        down = time.monotonic()
        last = display.snapshot()[-1][3]
        assert not list(tmp_path.glob(".*.tmp"))  # no temporary file left behind

        time.sleep(1.0)  # the gap to predict
        spawn = time.monotonic()
        svc = service(endpoint, keys, state)
        assert wait_for_tracker(session, keys, 1, timeout=30)
        alive = time.monotonic() - spawn
        assert frames.wait_for(lambda _: frames_with(frames, names, spawn), 30), \
            "the picture did not come back"
        back = frames_with(frames, names, spawn)[0][0] - spawn
        print(f"\nrestart: all {TARGETS} tracks back in the frames {back:.3f} s after the "
              f"new process was started (its liveliness token after {alive:.3f} s: "
              f"interpreter, imports, session), no measurement; service down "
              f"{spawn - down:.1f} s")
        after = {b["id"]: b for b in get_all(session, keys.space("tracks"))}
        assert after == before  # filtered states exactly as saved, each at its own t
        def shown(samples: list) -> list:  # display states put since the restart
            return [b for t, _, k, b in samples if k == "PUT" and t >= spawn]
        # every track's display key comes back too (the first frames may go out before
        # the service sees the subscriber of display/**, and a display put may be dropped
        # under congestion: the next frame's puts it again)
        assert display.wait_for(lambda s: {b["id"] for b in shown(s)} == names, 10)
        first = {b["id"]: b for b in reversed(shown(display.snapshot()))}  # the first of each
        for i, b in first.items():  # the gap is predicted: older, less certain
            old = [s for _, _, k, s in display.snapshot() if k == "PUT" and s["id"] == i
                   and s["t"] <= last["t"]][-1]
            assert b["t"] > old["t"] + 1.0 and b["age"] > old["age"] + 1.0
            assert b["sigma"] > old["sigma"]
        assert np.isfinite([b["sigma"] for b in first.values()]).all()

        def aged(samples: list) -> dict:  # each track's restored states past 2.5 intervals
            out: dict = {}
            for t, _, k, b in samples:
                if k == "PUT" and t >= spawn and b["age"] > 2.5 + 0.1:  # 1 s scans
                    out.setdefault(b["id"], []).append(b)
            return out
        # the predicted gap grows until every track has gone 2.5 scan intervals unseen
        assert display.wait_for(lambda s: set(aged(s)) == names, 30), "no track turned coasting"
        for i, states in aged(display.snapshot()).items():
            assert all(b["status"] == "coasting" for b in states), (i, states[0])
    finally:
        if session is not None:
            session.close()
        if svc is not None:
            svc.stop()
        router.stop()


@pytest.mark.slow
def test_lockstep_restart_and_a_corrupt_state_file(tmp_path, service_factory):
    state = tmp_path / "lockstep.state"
    svc, session = service_factory("--clock", "lockstep", "--state", str(state), ns="rl")
    svc.feed("maneuver", "--runs", "3")
    before = {b["id"]: b for b in get_all(session, svc.keys.space("tracks"))}
    assert len(before) == 3
    svc.stop()
    assert state.is_file()

    again = ServiceProc("--clock", "lockstep", "--state", str(state), ns="rl")
    try:
        watcher = client_session(again.endpoint)
        assert wait_for_tracker(watcher, again.keys, 1, timeout=30)
        assert {b["id"]: b for b in get_all(watcher, again.keys.space("tracks"))} == before
        status = get_all(watcher, again.keys.status)[0]
        assert status["tracks"] == 3 and status["meas_accepted"] == 0
        watcher.close()
    finally:
        err = again.stop()
    assert "restored 3 tracks" in err and "lockstep picture at t=" in err

    state.write_bytes(state.read_bytes()[:200])  # a checkpoint cut short
    bad = ServiceProc("--clock", "lockstep", "--state", str(state), ns="rl")
    try:
        watcher = client_session(bad.endpoint)
        assert wait_for_tracker(watcher, bad.keys, 1, timeout=30)
        assert get_all(watcher, bad.keys.status)[0]["tracks"] == 0
        watcher.close()
    finally:
        err = bad.stop()
    lines = [ln for ln in err.splitlines() if "state file" in ln]
    assert len(lines) == 1 and "refused" in lines[0] and "starting empty" in lines[0], err
    assert "Traceback" not in err
    assert (tmp_path / "lockstep.state.refused").is_file()
