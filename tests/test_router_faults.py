"""Router faults: the compose topology (a router, the service, a feed and a viewer, all
clients of the router, from the deploy/ config files) on loopback; the router is stopped
and started again while a realtime feed runs. Tracking must resume by itself with every
track kept: no deletion, every target updated again (its update count continuing, not a
new track). The reconnect time is printed (pytest -s shows it; docs/operations.md)."""

from __future__ import annotations

import subprocess
import sys
import time
import uuid

import pytest
import zenoh
from routers import DEPLOY, ENV, RouterProc, Stamped, client_conf, ids_since

from zenoh_track.clients import ServiceProcess
from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import Keys, free_port, unpack, wait_for_tracker

TARGETS = 12


def status(session: zenoh.Session, keys: Keys) -> dict:
    for reply in session.get(keys.status, timeout=10):
        return unpack(reply.ok.payload.to_bytes())
    raise AssertionError("no status reply")


@pytest.mark.slow
def test_router_restart_resumes_tracking_with_every_track_kept():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys(f"rf{uuid.uuid4().hex[:8]}")
    names = {f"swarm-{i:05d}" for i in range(TARGETS)}
    router = RouterProc(DEPLOY / "router.json5", endpoint)
    router.start()
    procs: list[subprocess.Popen] = []
    session = None
    svc = None
    try:
        svc = ServiceProcess("-c", str(DEPLOY / "shard-a.json5"), "--instance", "rf",
                             ns=keys.ns, clock=None, connect=endpoint)
        session = zenoh.open(client_conf(DEPLOY / "client.json5", endpoint))
        tracks = Stamped(session, keys.space("tracks"))
        display = Stamped(session, keys.space("display"))
        assert wait_for_tracker(session, keys, 1, timeout=30), "service not up"
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets",
             str(TARGETS),
             "--duration", "60", "--realtime", "-c", str(DEPLOY / "client.json5"),
             "-e", endpoint, "--ns", keys.ns],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV))
        start = time.monotonic()
        assert tracks.wait_for(lambda s: set(ids_since(s, start)) == names, 30), \
            "tracking did not start"
        assert tracks.wait_for(lambda s: {b["id"] for _, _, k, b in s if k == "PUT"
                                          and b["updates"] >= 2} >= names, 30), \
            "no second scan"  # every track established
        before = status(session, keys)
        assert before["tracks"] == TARGETS, before
        updates_before = {b["id"]: b["updates"] for _, _, k, b in tracks.snapshot()
                          if k == "PUT"}

        router.stop()
        down = time.monotonic()
        time.sleep(3.0)  # everyone notices: the service's frames and the feed's scans drop
        up = router.start()
        assert tracks.wait_for(lambda s: set(ids_since(s, up)) == names, 20), \
            f"tracking did not resume: {sorted(names - set(ids_since(tracks.snapshot(), up)))}"
        back = ids_since(tracks.snapshot(), up)
        first, last = min(back.values()) - up, max(back.values()) - up
        shown = ids_since(display.snapshot(), up)
        print(f"\nrouter down {up - down:.1f} s; after its return: first track update "
              f"{first:.3f} s, every track updated {last:.3f} s (the feed scans each "
              f"target once a second), first display state {min(shown.values()) - up:.3f} s")

        after = status(session, keys)
        assert after["tracks"] == TARGETS and after["tracks_deleted"] == 0, after
        kinds = {k for _, _, k, _ in tracks.snapshot() + display.snapshot()}
        assert kinds == {"PUT"}, "a track was deleted"
        resumed = {b["id"]: b["updates"] for t, _, k, b in tracks.snapshot() if t >= up}
        # the same tracks carry on: their update counts continue past the outage
        assert all(resumed[i] > updates_before[i] for i in names), (updates_before, resumed)
        assert after["meas_accepted"] > before["meas_accepted"]
        assert after["meas_lost"] > 0  # what the feed sent into the outage is reported
        print(f"measurements the feed sent while the router was away, counted lost by 'seq': "
              f"{after['meas_lost']}")
        assert last < 2.0 + 1.0 + 2.0, f"slow reconnect: {last:.3f} s"  # retry + a scan + slack
    finally:
        if session is not None:
            session.close()
        for p in reversed(procs):
            stop(p)
        if svc is not None:
            svc.stop()
        router.stop()
