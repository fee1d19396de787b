"""`track-feed SCENARIO`: publish a reference scenario's labelled measurements.

Measurements go to `<ns>/meas/<sensor>/<target>` with congestion control BLOCK (nothing
is lost), as fast as possible or at the pace of simulation time (`--realtime`); the feed
ends with a `<ns>/clock` message one scan after the last, then waits for every tracker to
confirm receipt (a status query behind the data) before it closes its session, which
would drop whatever its links still queue. `--truth` also publishes the true states on
`<ns>/truth/<target>` (an extension key) for evaluation.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator

import zenoh

from service.wire import (
    BLOCK_WAIT_US,
    Keys,
    add_zenoh_args,
    pack,
    patient,
    wait_for_tracker,
    zenoh_config,
)

from . import scenarios


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-feed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", choices=[*scenarios.SCENARIOS, "swarm"],
                   help="display (A, 30 Hz display), radar3d (B, CMKF vs EKF), "
                        "maneuver (C, manoeuvring target), swarm (many straight targets)")
    p.add_argument("--runs", type=int, default=1, help="Monte Carlo copies, one target each")
    p.add_argument("--targets", type=int, default=100, help="swarm: number of targets")
    p.add_argument("--duration", type=float, default=60.0, help="swarm: seconds simulated")
    p.add_argument("--sectors", type=int, default=32,
                   help="swarm: reports per radar turn, each sent as the beam leaves it")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sensor", default="radar1", help="sensor chunk of the keys")
    p.add_argument("--realtime", action="store_true", help="pace scans by simulation time")
    p.add_argument("--t0", type=float, default=0.0, help="simulation time offset, s")
    p.add_argument("--truth", action="store_true", help="also publish <ns>/truth/<target>")
    p.add_argument("--trackers", type=int, default=1,
                   help="wait for this many tracker liveliness tokens (0: do not wait)")
    add_zenoh_args(p)
    return p


def scans(args: argparse.Namespace) -> Iterator[scenarios.Scan]:
    if args.scenario == "swarm":
        return scenarios.swarm(args.targets, args.seed, args.duration, sectors=args.sectors)
    return scenarios.SCENARIOS[args.scenario](runs=args.runs, seed=args.seed)


def stamped(body: dict, t_scan: float, offset: float, **extra: object) -> dict:
    """The message: `t` first, the body's own t (a radar's beam crossing time) if it
    has one else the scan's, shifted by `offset`."""
    return {"t": body.get("t", t_scan) + offset, **extra,
            **{k: v for k, v in body.items() if k != "t"}}


def publish(session: zenoh.Session, args: argparse.Namespace) -> int:
    """Publish every scan; return the number of measurements sent."""
    keys = Keys(args.ns)
    block = zenoh.CongestionControl.BLOCK
    # one key expression per target, put on the session: declaring a publisher per
    # target costs O(declared) in zenoh, O(N^2) for a swarm
    meas_keys: dict[str, zenoh.KeyExpr] = {}
    truth_keys: dict[str, zenoh.KeyExpr] = {}
    put = session.put
    sent, seq, t_last = 0, 0, args.t0
    wall0 = time.monotonic()
    for t0, meas, truth in scans(args):
        t = t0 + args.t0
        if args.realtime:
            delay = wall0 + (t - args.t0) - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # pacing to simulation time is the point here
        if args.truth:
            for target, state in truth:
                ke = truth_keys.get(target) or truth_keys.setdefault(
                    target, zenoh.KeyExpr(keys.truth(target)))
                put(ke, pack(stamped(state, t0, args.t0)), congestion_control=block)
        for target, m in meas:
            ke = meas_keys.get(target) or meas_keys.setdefault(
                target, zenoh.KeyExpr(keys.meas(args.sensor, target)))
            put(ke, pack(stamped(m, t0, args.t0, seq=seq)), congestion_control=block)
            seq += 1
            sent += 1
        t_last = t
    period = scenarios.PERIODS[args.scenario]
    session.put(keys.clock, pack({"t": t_last + period}), congestion_control=block)
    return sent


def delivered(session: zenoh.Session, keys: Keys, trackers: int,
              timeout: float = BLOCK_WAIT_US / 1e6) -> bool:
    """Wait until `trackers` trackers have received everything sent: closing a session
    drops what its links still queue, and a status query travels behind the data on
    each link, so its answer means the data arrived."""
    replies = session.get(keys.status, target=zenoh.QueryTarget.ALL,
                          consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout)
    return sum(1 for r in replies if r.ok is not None) >= trackers


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    conf = zenoh_config(args)
    session = zenoh.open(conf if args.config else patient(conf))  # block, never drop
    try:
        if args.trackers and not wait_for_tracker(session, Keys(args.ns), args.trackers):
            sys.exit(f"track-feed: no tracker alive on '{args.ns}' after 30 s "
                     "(start track-service, or pass --trackers 0)")
        start = time.monotonic()
        try:
            n = publish(session, args)
        except KeyboardInterrupt:
            return
        print(f"track-feed: {args.scenario}: {n} measurements in "
              f"{time.monotonic() - start:.2f} s", flush=True)
        if args.trackers and not delivered(session, Keys(args.ns), args.trackers):
            sys.exit(f"track-feed: fewer than {args.trackers} tracker(s) confirmed receipt")
    finally:
        session.close()


if __name__ == "__main__":
    main()
