"""`track-feed SCENARIO`: publish a reference scenario's labelled measurements, or the
unlabelled scans of a data-association scenario.

Measurements go to `<ns>/meas/<sensor>/<target>`, and the scans of `crossing`, `manoeuvres`,
`multisensor` and `swarm --plots` (clients/feeds/feed_plots.py) to `<ns>/plots/<sensor>`, with
congestion control BLOCK (nothing is lost), as fast as possible or at the pace of
simulation time (`--realtime`); the feed ends with a `<ns>/clock` message one scan after
the last, then waits for every tracker to confirm receipt (a status query behind the
data) before it closes its session, which would drop whatever its links still queue.
`--truth` also publishes the true states on `<ns>/truth/<target>` (an extension key) for
evaluation.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterator

import numpy as np
import zenoh

from zenoh_track.clients.feeds import feed_plots, plotgen, scenarios
from zenoh_track.wire import (
    BLOCK_WAIT_US,
    MSGPACK_ENCODING,
    Keys,
    add_zenoh_args,
    f64_bin,
    on_signals,
    open_session,
    pack,
    wait_for_tracker,
)

# one scan: its time (shifted by --t0), its messages (truth first), measurements among them
Batch = tuple[float, list[tuple[zenoh.KeyExpr, bytes]], int]


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-feed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", choices=[*scenarios.SCENARIOS, "swarm", *feed_plots.SCENARIOS,
                                        "manoeuvres"],
                   help="display (A, 30 Hz display), radar3d (B, CMKF vs EKF), "
                        "maneuver (C, manoeuvring target), swarm (many straight targets), "
                        "crossing and multisensor (unlabelled scans), manoeuvres "
                        "(aircraft turning at 1 to 7 g, one 3-D radar; scans, or --labelled)")
    p.add_argument("--runs", type=int, default=1,
                   help="Monte Carlo copies, one target each (display, radar3d, maneuver)")
    p.add_argument("--targets", type=int, default=None,
                   help="swarm: number of targets (default 100); crossing, multisensor: "
                        "default 20")
    p.add_argument("--duration", type=float, default=60.0, help="swarm: seconds simulated")
    p.add_argument("--sectors", type=int, default=32,
                   help="swarm: reports per radar turn, each sent as the beam leaves it")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sensor", default="radar1", help="sensor chunk of the keys")
    p.add_argument("--realtime", action="store_true", help="pace scans by simulation time")
    p.add_argument("--t0", type=float, default=0.0, help="simulation time offset, s")
    p.add_argument("--truth", action="store_true", help="also publish <ns>/truth/<target>")
    p.add_argument("--batched", action="store_true",
                   help="send each scan's (swarm: each sector's) measurements as one columnar "
                        "message on <ns>/scan/<sensor> (contract 1.1) instead of one message "
                        "per measurement")
    p.add_argument("--trackers", type=int, default=1,
                   help="wait for this many tracker liveliness tokens (0: do not wait)")
    p.add_argument("--receipt-timeout", type=float, default=BLOCK_WAIT_US / 1e6,
                   metavar="S", help="how long to wait at the end for the trackers to confirm "
                   "receipt (a status answer, behind everything queued; default %(default)g)")
    feed_plots.add_args(p)
    add_zenoh_args(p)
    return p


def scans(args: argparse.Namespace) -> Iterator[scenarios.Scan]:
    if args.scenario == "manoeuvres":
        return feed_plots.scenario(args).labelled()
    if args.scenario == "swarm":
        return scenarios.swarm(feed_plots.targets(args), args.seed, args.duration,
                               sectors=args.sectors)
    return scenarios.SCENARIOS[args.scenario](runs=args.runs, seed=args.seed)


def stamped(body: dict, t_scan: float, offset: float, **extra: object) -> dict:
    """The message: `t` first, the body's own t (a radar's beam crossing time) if it
    has one else the scan's, shifted by `offset`."""
    return {"t": body.get("t", t_scan) + offset, **extra,
            **{k: v for k, v in body.items() if k != "t"}}


class KeyCache(dict[str, zenoh.KeyExpr]):
    """Key expressions made once per name and put on the session: declaring a publisher
    per target costs O(declared) in zenoh, O(N^2) for a swarm."""

    def __init__(self, key: Callable[[str], str]) -> None:
        super().__init__()
        self.key = key

    def __missing__(self, name: str) -> zenoh.KeyExpr:
        ke = self[name] = zenoh.KeyExpr(self.key(name))
        return ke


def labelled(args: argparse.Namespace, keys: Keys) -> Iterator[Batch]:
    """The labelled scenario's scans: truth, then measurements numbered by `seq`."""
    meas_keys = KeyCache(lambda target: keys.meas(args.sensor, target))
    truth_keys = KeyCache(keys.truth)
    seq = 0
    if args.scenario == "swarm" and not args.truth:  # from columns: no truth made unasked
        for sent, s in scenarios.swarm_sectors(feed_plots.targets(args), args.seed,
                                                args.duration, sectors=args.sectors):
            names, sr, sa = s.names, s.sr, s.sa
            out = [(meas_keys[names[i]],
                    pack({"t": t + args.t0, "seq": seq + j, "r": r, "az": az, "el": el,
                          "sr": sr, "saz": sa, "sel": sa}))
                   for j, (i, t, r, az, el) in enumerate(zip(
                       s.idx.tolist(), s.t.tolist(), s.r.tolist(), s.az.tolist(),
                       s.el.tolist(), strict=True))]
            seq += len(out)
            yield sent + args.t0, out, len(out)
        return
    for t0, meas, truth in scans(args):
        out = [(truth_keys[target], pack(stamped(state, t0, args.t0)))
               for target, state in truth] if args.truth else []
        for target, m in meas:
            out.append((meas_keys[target], pack(stamped(m, t0, args.t0, seq=seq))))
            seq += 1
        yield t0 + args.t0, out, len(meas)


def batched(args: argparse.Namespace, keys: Keys) -> Iterator[Batch]:
    """The labelled scenario's scans as batched scans: one `<ns>/scan/<sensor>` message
    each, `t` and the polar values as bins of float64, noise as floats when shared."""
    key = zenoh.KeyExpr(keys.scan(args.sensor))
    truth_keys = KeyCache(keys.truth)
    if args.scenario == "swarm" and not args.truth:  # columns all the way (100,000 targets)
        for sent, s in scenarios.swarm_sectors(feed_plots.targets(args), args.seed,
                                                args.duration, sectors=args.sectors):
            if not len(s.idx):
                yield sent + args.t0, [], 0
                continue
            names = s.names
            msg = {"ids": [names[i] for i in s.idx.tolist()], "t": _f64(s.t + args.t0),
                   "r": _f64(s.r), "az": _f64(s.az), "el": _f64(s.el), "sr": s.sr,
                   "saz": s.sa, "sel": s.sa}
            yield sent + args.t0, [(key, pack(msg))], len(s.idx)
        return
    for t0, meas, truth in scans(args):
        out = [(truth_keys[target], pack(stamped(state, t0, args.t0)))
               for target, state in truth] if args.truth else []
        if meas:
            out.append((key, pack(columnar([stamped(m, t0, args.t0) for _, m in meas],
                                           [target for target, _ in meas]))))
        yield t0 + args.t0, out, len(meas)


def _f64(a: object) -> bytes:
    """A column as a bin of little-endian float64 (what f64_bin makes of its floats)."""
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def columnar(rows: list[dict], ids: list[str]) -> dict:
    """One batched scan from the messages of its rows (all polar or all Cartesian)."""
    msg: dict = {"ids": ids, "t": f64_bin([m["t"] for m in rows])}
    fields = ("r", "az", "el") if "r" in rows[0] else ("pos",)
    for k in fields:
        if all(k in m for m in rows):
            flat = [x for m in rows for x in m[k]] if k == "pos" else [m[k] for m in rows]
            msg[k] = f64_bin(flat)
    if "pos" in msg:
        msg["dim"] = len(rows[0]["pos"])
    for k in ("sr", "saz", "sel", "sigma", "sensor_pos"):
        values = [m[k] for m in rows if k in m]
        if len(values) == len(rows) and all(v == values[0] for v in values):
            msg[k] = values[0]
        elif values and len(values) == len(rows) and k != "sensor_pos":
            msg[k] = f64_bin(values)
    return msg


def plots(args: argparse.Namespace, keys: Keys, sc: plotgen.Scenario) -> Iterator[Batch]:
    """The unlabelled scans of `sc`: truth ({t, pos, vel}, 2-D or 3-D as the scenario's),
    then one plots scan."""
    plot_keys, truth_keys = KeyCache(keys.plots), KeyCache(keys.truth)
    for scan in sc:
        scan = scan._replace(t=scan.t + args.t0)
        out = [(truth_keys[target], pack({"t": scan.t, "pos": pos.tolist(),
                                          "vel": vel.tolist()}))
               for target, (pos, vel) in scan.truth.items()] if args.truth else []
        out.append((plot_keys[scan.sensor], sc.payload(scan, args.columnar)))
        yield scan.t, out, len(scan.dets)


def publish(session: zenoh.Session, args: argparse.Namespace) -> int:
    """Publish every scan; return the number of measurements (detections) sent."""
    keys = Keys(args.ns)
    block = zenoh.CongestionControl.BLOCK
    if feed_plots.is_plots(args):
        sc = feed_plots.scenario(args)
        batches, period = plots(args, keys, sc), sc.dt
    else:
        batches = batched(args, keys) if args.batched else labelled(args, keys)
        period = args.period if args.scenario == "manoeuvres" else \
            scenarios.PERIODS[args.scenario]
    put, enc = session.put, zenoh.Encoding(MSGPACK_ENCODING)
    sent, t_last = 0, args.t0
    wall0 = time.monotonic()
    for t, messages, n in batches:
        if args.realtime:
            delay = wall0 + (t - args.t0) - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # pacing to simulation time is the point here
        for ke, payload in messages:
            put(ke, payload, encoding=enc, congestion_control=block)
        sent += n
        t_last = t
    put(keys.clock, pack({"t": t_last + period}), encoding=enc, congestion_control=block)
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
    on_signals(interrupt=True)
    session = open_session(args, block=True, stamp=True)  # block, never drop; stamped
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
        if args.trackers and not delivered(session, Keys(args.ns), args.trackers,
                                           args.receipt_timeout):
            sys.exit(f"track-feed: fewer than {args.trackers} tracker(s) confirmed receipt")
    finally:
        session.close()


if __name__ == "__main__":
    main()
