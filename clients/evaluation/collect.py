"""Run a reference scenario through a lockstep track service over Zenoh and collect what it
publishes (`tracks/*`, `frame`, and optionally interception summaries) for track-eval;
or an unlabelled-scan scenario, collecting the tracks shown at its scan instants.
"""

from __future__ import annotations

import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

import zenoh

from zenoh_track.clients.feeds import feed, feed_plots, scenarios
from zenoh_track.clients.intercept.guidance import Law
from zenoh_track.clients.intercept.intercept import Interceptors
from zenoh_track.clients.lib import Frame, Merge, ServiceProcess
from zenoh_track.wire import Keys, peer_config, unpack, wait_for_tracker
from zenoh_track.wire.cli import open_or_exit


@dataclass
class Collected:
    """What one service run published: tracks/ messages by (id, t), frames, and per
    guidance law the interception summary."""

    tracks: dict[tuple[str, float], dict] = field(default_factory=dict)
    frames: list[tuple[float, list[dict]]] = field(default_factory=list)
    interception: dict[str, dict] = field(default_factory=dict)  # guidance -> summary


def lockstep_service(ns: str, service_args: list[str]) -> ServiceProcess:
    """A lockstep service on a free loopback port (its output in a log file of its own,
    which keeps --json output clean)."""
    return ServiceProcess(*service_args, ns=ns, clock="lockstep")


def option(service_args: list[str], name: str, default: float) -> float:
    """The value of a numeric service option in `service_args` (the last one given)."""
    at = [i for i, a in enumerate(service_args[:-1]) if a == name]
    return float(service_args[at[-1] + 1]) if at else default


def run_through_service(scenario: str, runs: int, seed: int, service_args: list[str],
                        endpoint: str | None = None, ns: str | None = None,
                        intercept: list[str] | None = None) -> Collected:
    """Start a lockstep service (unless `endpoint` names a running one), publish the
    scenario to it and collect what it publishes; with `intercept` (guidance laws), fly
    one interceptor per target and law on the display keys, in lockstep."""
    ns = ns or f"eval{uuid.uuid4().hex[:8]}"
    proc = None
    if endpoint is None:
        proc = lockstep_service(ns, service_args)
        endpoint = proc.endpoint
    keys = Keys(ns)
    out = Collected()
    done = threading.Event()
    arrived = threading.Condition()  # notified by every tracks/ message
    scans = list(scenarios.SCENARIOS[scenario](runs=runs, seed=seed))
    rate, lag = option(service_args, "--rate", 30.0), option(service_args, "--lag", 0.0)
    t_end = scans[-1][0] + scenarios.PERIODS[scenario] - 1.5 / rate - lag

    def on_track(s: Any) -> None:
        if s.kind == zenoh.SampleKind.PUT:
            m = unpack(s.payload.to_bytes())
            with arrived:
                out.tracks[(m["id"], round(m["t"], 6))] = m
                arrived.notify_all()

    # the frames of every instance of the namespace (-e: a sharded service, say), merged
    # as every client merges them; lockstep: each instant waits for every instance
    merge = Merge(hold=None, stale=None)

    def on_frame(s: Any) -> None:
        for pic in merge.add(Frame.from_payload(s.payload.to_bytes()), time.monotonic()):
            out.frames.append((pic.t, pic.rows()))
            if pic.t >= t_end:
                done.set()

    session = (zenoh.open(peer_config(endpoint)) if proc else  # -e: a running service
               open_or_exit(lambda: peer_config(endpoint), prog="track-eval"))
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
        if proc is not None:
            proc.stop()
    return out


# status and 2-D position of each track shown at one display instant
Shown = dict[str, tuple[list[float], str]]


def run_plots_through_service(feed_argv: list[str], service_args: list[str],
                              timeout: float = 600.0) -> dict[float, Shown]:
    """Start a lockstep service, publish the unlabelled scenario `feed_argv` (track-feed's
    arguments) to it, and collect the `display/` messages (position and status) at the
    scenario's scan instants, keyed by round(t, 6). `service_args` must set a `--rate`
    whose display instants include every scan instant; an instant's `frame` (published
    just before its `display/` messages) says how many tracks to expect."""
    ns = f"eval{uuid.uuid4().hex[:8]}"
    args = feed.parser().parse_args([*feed_argv, "--ns", ns])
    sc = feed_plots.scenario(args)
    times = [s.t for s in sc]
    needed = {round(t, 6) for t in times}
    rate = option(service_args, "--rate", 30.0)
    if any(abs(t * rate - round(t * rate)) > 1e-6 for t in times):
        raise SystemExit(f"track-eval: --rate {rate:g} has no display instant at some scan")
    keys = Keys(ns)
    shown: dict[float, Shown] = {t: {} for t in needed}
    expect: dict[float, int] = {}
    arrived = threading.Condition()

    merge = Merge(hold=None, stale=None)  # the client library's picture: every instant

    def on_frame(s: Any) -> None:
        for pic in merge.add(Frame.from_payload(s.payload.to_bytes()), time.monotonic()):
            t = round(pic.t, 6)
            if t in needed:
                with arrived:
                    expect[t] = len(pic)
                    arrived.notify_all()

    def on_display(s: Any) -> None:
        if s.kind == zenoh.SampleKind.PUT:
            m = unpack(s.payload.to_bytes())
            t = round(m["t"], 6)
            if t in needed:
                with arrived:
                    shown[t][m["id"]] = (m["pos"][:2], m["status"])
                    if len(shown[t]) == expect.get(t):
                        arrived.notify_all()

    def complete() -> bool:
        return len(expect) == len(needed) and all(len(shown[t]) >= n
                                                  for t, n in expect.items())

    proc = lockstep_service(ns, service_args)
    endpoint = proc.endpoint
    session = zenoh.open(peer_config(endpoint))
    try:
        direct = [zenoh.handlers.Callback(f, indirect=False) for f in (on_frame, on_display)]
        subs = [session.declare_subscriber(keys.frame, direct[0]),
                session.declare_subscriber(keys.display("*"), direct[1])]
        if not wait_for_tracker(session, keys, 1, timeout=30):
            raise SystemExit(f"track-eval: no tracker on {endpoint} ns={ns}")
        feed.publish(session, args)
        with arrived:
            if not arrived.wait_for(complete, timeout):
                raise SystemExit(f"track-eval: {len(needed) - len(expect)} scan instants "
                                 "not displayed")
        for sub in subs:
            sub.undeclare()
    finally:
        session.close()
        if proc is not None:
            proc.stop()
    return shown
