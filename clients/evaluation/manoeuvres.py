"""`track-eval manoeuvres`: does the service hold every aircraft through its manoeuvres?

Each Monte Carlo run r (seed `--seed` + r) starts a lockstep service (`--rate 1`, so
that every scan instant, a whole second, is a display instant), publishes the
`manoeuvres` scenario (clients/feeds/manoeuvres.py, with track-feed's code) and collects the
`frame` at every scan instant (each track's position and status) and the `states`
messages (each updated track's x and P). Scored by clients/evaluation/manoeuvre_score.py: per
class, the track breaks, the fraction of scans held after confirmation, and RMSE and
NEES while manoeuvring and on straight legs.

Configurations: `default` (the service without options) and `ncv-blair`, a single
NCV filter (`--filter cv`) whose white acceleration follows Blair's rule for a 7 g
target at the run's scan period and the radar's cross-range noise at 36 km
(`manoeuvre_score.blair_q`); `--config` picks some, `--service-arg` adds options to
every service.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
import uuid
from typing import Any

import numpy as np
import zenoh

from zenoh_track.clients.evaluation import manoeuvre_score as ms
from zenoh_track.clients.evaluation.collect import lockstep_service
from zenoh_track.clients.feeds import feed, feed_plots
from zenoh_track.clients.feeds.manoeuvres import CLASSES, SLOW_CLASSES
from zenoh_track.clients.lib import Frame, Merge
from zenoh_track.wire import Keys, add_version, on_signals, peer_config, unpack, wait_for_tracker

A_MAX = 7 * 9.80665  # m/s^2: the largest manoeuvre of the scenario
SIGMA = 1.5e-3 * 36_000.0  # m: the radar's cross-range noise at the aircraft's distance
CONFIGS = ("default", "ncv-blair")


def service_args(config: str, period: float) -> list[str]:
    if config == "default":
        return []
    if config == "ncv-blair":
        return ["--filter", "cv", "--q", f"{ms.blair_q(A_MAX, period, SIGMA):.3f}"]
    raise SystemExit(f"track-eval: unknown configuration {config!r}; one of {CONFIGS}")


def through_service(feed_argv: list[str], options: list[str],
                    timeout: float = 600.0) -> tuple[ms.Shown, ms.States]:
    """Run one feed through a new lockstep service: the established tracks' positions at
    every scan instant (`frame`) and the states of the tracks updated there (`states`)."""
    ns = f"eval{uuid.uuid4().hex[:8]}"
    args = feed.parser().parse_args([*feed_argv, "--ns", ns])
    sc = feed_plots.scenario(args)
    needed = {round(t, 6) for t in sc.times.tolist()}
    last = max(needed)
    keys = Keys(ns)
    shown: ms.Shown = {}
    states: ms.States = {}
    arrived = threading.Condition()

    merge = Merge(hold=None, stale=None)  # the client library's picture: every instant

    def on_frame(s: Any) -> None:
        for pic in merge.add(Frame.from_payload(s.payload.to_bytes()), time.monotonic()):
            t = round(pic.t, 6)
            if t in needed:  # the established tracks (a frame without status: all)
                with arrived:
                    shown[t] = {k: pic.pos[i].copy() for i, k in enumerate(pic.id_list)
                                if pic.codes[i] != 0}
                    arrived.notify_all()

    def on_states(s: Any) -> None:
        m = unpack(s.payload.to_bytes())
        n, dim = len(m["ids"]), m["n"]
        t = np.frombuffer(m["t"], "<f8")
        x = np.frombuffer(m["x"], "<f8").reshape(n, dim)
        p = np.frombuffer(m["P"], "<f8").reshape(n, dim, dim)
        with arrived:
            for i, k in enumerate(m["ids"]):
                states.setdefault(round(float(t[i]), 6), {})[k] = (x[i].copy(), p[i].copy())
            arrived.notify_all()

    proc = lockstep_service(ns, ["--rate", "1", "--no-display-keys", *options])
    endpoint = proc.endpoint
    session = zenoh.open(peer_config(endpoint))
    try:
        subs = [session.declare_subscriber(keys.frame,
                                           zenoh.handlers.Callback(on_frame, indirect=False)),
                session.declare_subscriber(keys.states,
                                           zenoh.handlers.Callback(on_states, indirect=False))]
        if not wait_for_tracker(session, keys, 1, timeout=30):
            raise SystemExit(f"track-eval: no tracker on {endpoint} ns={ns}")
        feed.publish(session, args)
        with arrived:
            if not arrived.wait_for(lambda: needed <= shown.keys(), timeout):
                raise SystemExit(f"track-eval: {len(needed - shown.keys())} scan instants "
                                 "not in a frame")
            # the states of the last scan precede its frame; a scan may update no track
            arrived.wait_for(lambda: last in states, 5.0)
        for sub in subs:
            sub.undeclare()
    finally:
        session.close()
        proc.stop()
    return shown, states


def feed_argv(args: argparse.Namespace, period: float, seed: int) -> list[str]:
    return ["manoeuvres", "--period", f"{period:g}", "--pd", f"{args.pd:g}", "--clutter",
            f"{args.clutter:g}", "--per-class", str(args.per_class), "--seed", str(seed),
            "--classes", ",".join(args.classes),
            *(["--labelled"] if args.labelled else [])]


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-eval manoeuvres", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=10, help="Monte Carlo runs per scan period")
    p.add_argument("--per-class", type=int, default=2, help="aircraft of each class a run")
    p.add_argument("--classes", type=feed_plots.classes, default=CLASSES,
                   help=f"classes, comma-separated (default {','.join(CLASSES)}; the slow and "
                        f"tight flyers: {','.join(SLOW_CLASSES)})")
    p.add_argument("--period", type=float, action="append", default=[],
                   help="scan period, s (repeatable; default 1, 2, 4 and 5)")
    p.add_argument("--pd", type=float, default=0.9,
                   help="the radar's detection probability (stated to the service too)")
    p.add_argument("--clutter", type=float, default=10.0, help="false detections a scan")
    p.add_argument("--labelled", action="store_true",
                   help="labelled measurements (no clutter) instead of scans")
    p.add_argument("--config", action="append", default=[], choices=CONFIGS,
                   help="configurations to run (repeatable; default all)")
    p.add_argument("--service-arg", action="append", default=[],
                   help="extra argument passed to every service (repeatable)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--onset", action="store_true",
                   help="also RMSE and NEES while manoeuvring by scans since each onset "
                        "(where the NEES comes from: docs/accuracy.md)")
    p.add_argument("--json", action="store_true", help="print the summaries as JSON")
    add_version(p)
    return p


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parser().parse_args(argv)
    on_signals(interrupt=True)
    out: dict[str, Any] = {}
    form = "labelled" if args.labelled else f"Pd {args.pd:g}, {args.clutter:g} clutter a scan"
    for period in args.period or [1.0, 2.0, 4.0, 5.0]:
        for config in args.config or CONFIGS:
            start, got = time.monotonic(), []
            # the radar's Pd stated to the service, as its operator would
            options = [*service_args(config, period), "--pd", f"{args.pd:g}",
                       *args.service_arg]
            for r in range(args.runs):
                fa = feed_argv(args, period, args.seed + r)
                shown, states = through_service(fa, options)
                sc = feed_plots.scenario(feed.parser().parse_args(fa))
                got += ms.score(sc, shown, states, args.labelled)
            sums = ms.summary(got)
            out[f"{config} {period:g} s"] = sums
            if not args.json:
                print(ms.table(f"{config} ({' '.join(options) or 'no options'}): period "
                               f"{period:g} s, {form}, {args.runs} runs x {args.per_class} "
                               f"aircraft a class, seeds {args.seed}-{args.seed + args.runs - 1}"
                               f" ({time.monotonic() - start:.0f} s)", sums), flush=True)
                if args.onset:
                    print(ms.onset_table([a for a in got if a.kind != "straight"], period),
                          flush=True)
    if args.json:
        print(json.dumps(out, indent=1))
    return out
