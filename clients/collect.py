"""Run a reference scenario through a lockstep track service over Zenoh and collect what it
publishes (`tracks/*`, `frame`, and optionally interception summaries) for track-eval.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import uuid
from dataclasses import dataclass, field
from typing import Any

import zenoh

from service.wire import Keys, decode_frame, free_port, peer_config, unpack, wait_for_tracker

from . import feed, scenarios
from .guidance import Law
from .intercept import Interceptors
from .procs import stop


@dataclass
class Collected:
    """What one service run published: tracks/ messages by (id, t), frames, and per
    guidance law the interception summary."""

    tracks: dict[tuple[str, float], dict] = field(default_factory=dict)
    frames: list[tuple[float, list[dict]]] = field(default_factory=list)
    interception: dict[str, dict] = field(default_factory=dict)  # guidance -> summary


def run_through_service(scenario: str, runs: int, seed: int, service_args: list[str],
                        endpoint: str | None = None, ns: str | None = None,
                        intercept: list[str] | None = None) -> Collected:
    """Start a lockstep service (unless `endpoint` names a running one), publish the
    scenario to it and collect what it publishes; with `intercept` (guidance laws), fly
    one interceptor per target and law on the display keys, in lockstep."""
    ns = ns or f"eval{uuid.uuid4().hex[:8]}"
    proc = None
    if endpoint is None:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        proc = subprocess.Popen([sys.executable, "-m", "service", "--clock", "lockstep",
                                 "-l", endpoint, "--ns", ns, *service_args],
                                stdout=subprocess.DEVNULL)  # keep --json output clean
    keys = Keys(ns)
    out = Collected()
    done = threading.Event()
    arrived = threading.Condition()  # notified by every tracks/ message
    scans = list(scenarios.SCENARIOS[scenario](runs=runs, seed=seed))
    rate = float(service_args[service_args.index("--rate") + 1]) \
        if "--rate" in service_args else 30.0
    lag = float(service_args[service_args.index("--lag") + 1]) \
        if "--lag" in service_args else 0.0
    t_end = scans[-1][0] + scenarios.PERIODS[scenario] - 1.5 / rate - lag

    def on_track(s: Any) -> None:
        if s.kind == zenoh.SampleKind.PUT:
            m = unpack(s.payload.to_bytes())
            with arrived:
                out.tracks[(m["id"], round(m["t"], 6))] = m
                arrived.notify_all()

    def on_frame(s: Any) -> None:
        m = unpack(s.payload.to_bytes())
        out.frames.append((m["t"], decode_frame(m)))
        if m["t"] >= t_end:
            done.set()

    session = zenoh.open(peer_config(endpoint))
    try:
        direct = [zenoh.handlers.Callback(f, indirect=False) for f in (on_track, on_frame)]
        subs = [session.declare_subscriber(keys.space("tracks"), direct[0]),
                session.declare_subscriber(keys.frame, direct[1])]
        if not wait_for_tracker(session, keys, 1, timeout=30):
            raise SystemExit(f"track-eval: no tracker on {endpoint} ns={ns}")
        flights = [Interceptors(Law(guidance=g), name=f"interceptor-{g}").attach(
            session, keys, like=f"{scenario}-", truth=True, publish=False)
            for g in intercept or []]
        args = feed.parser().parse_args([scenario, "--runs", str(runs), "--seed", str(seed),
                                         "--ns", ns, *(["--truth"] if flights else [])])
        feed.publish(session, args)
        for g, ic in zip(intercept or [], flights, strict=True):
            ic.wait(timeout=600)
            out.interception[g] = ic.summary()
            ic.detach()
        if not done.wait(600):
            raise SystemExit("track-eval: the service did not publish the last frame")
        # tracks/ and frame travel on separate keys: the last tracks/ may still be on its way
        expected = runs * len(scans)
        with arrived:
            arrived.wait_for(lambda: len(out.tracks) >= expected, timeout=30)
            missing = expected - len(out.tracks)
        if missing > 0:
            print(f"track-eval: WARNING: {missing} of {expected} tracks/ messages missing; "
                  "figures are partial", file=sys.stderr)
        for sub in subs:
            sub.undeclare()
    finally:
        session.close()
        stop(proc)
    return out
