"""`track-replay FILE`: publish a recording made by `track-record` into a Zenoh network.

Puts (and deletes) every recorded sample again, payload and Zenoh encoding as recorded,
in receive order: at the recorded pace (`--speed 1`, the default), scaled (`--speed
10`), or as fast as the receivers take them (`--fast`). `--only KEYEXPR` (repeatable)
replays part of it, `--feed` only a feed's keys (the service's inputs `meas/`, `plots/`,
`scan/`, `clock`, and `truth/`); `--remap OLD=NEW` moves keys from prefix OLD to NEW,
e.g. `--remap track=replay` into another namespace. A feed replayed into a lockstep
service behaves as `track-feed` does: it waits for the service's liveliness token,
publishes with congestion control BLOCK (a busy service holds the replay back; nothing
is dropped), and waits at the end until the service has confirmed receipt. A whole
session (`tracks/`, `display/`, `frame` too) can be replayed for displays, with no
service running. Before the first put it waits (`--subscribers-timeout`, 2 s) until Zenoh
knows a subscriber of every replayed key: a put made before the routing has learnt of a
subscriber reaches nobody. `--plot OUT.png` draws the recording instead
(clients/record/recording_plot.py).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import zenoh

from zenoh_track.clients.evaluation.progress import add_quiet_arg, bar
from zenoh_track.clients.feeds.feed import delivered
from zenoh_track.clients.record.files import Channel, Recording
from zenoh_track.wire import (
    BLOCK_WAIT_US,
    Keys,
    add_zenoh_args,
    need,
    on_signals,
    open_session,
    wait_for_tracker,
)

INPUTS = ("meas/**", "plots/**", "scan/**", "clock", "truth/**")  # a feed's keys under <ns>/


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-replay", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", metavar="FILE.mcap")
    p.add_argument("--only", action="append", default=[], metavar="KEYEXPR",
                   help="replay only the keys this key expression includes (repeatable; "
                        "matched against the recorded keys, before --remap)")
    p.add_argument("--feed", action="store_true",
                   help="replay only the feed's keys: " + ", ".join(f"<ns>/{k}" for k in INPUTS))
    p.add_argument("--remap", action="append", default=[], metavar="OLD=NEW",
                   help="publish keys under prefix OLD under NEW instead (repeatable; the "
                        "first that matches applies)")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=float, default=1.0, metavar="X",
                      help="replay X times as fast as recorded (default 1)")
    pace.add_argument("--fast", action="store_true",
                      help="as fast as the receivers take the samples")
    p.add_argument("--plot", metavar="OUT.png",
                   help="draw the recording (tracks seen from above, samples per second by "
                        "key; --only and --feed apply) to this PNG instead of replaying it")
    p.add_argument("--trackers", type=int, default=None, metavar="N",
                   help="wait for N trackers of the target namespace before replaying and "
                        "for their receipt at the end (default: 1 when the replay holds "
                        "service inputs, else 0)")
    p.add_argument("--receipt-timeout", type=float, default=BLOCK_WAIT_US / 1e6, metavar="S",
                   help="how long to wait at the end for the trackers to confirm receipt "
                        "(default %(default)g)")
    p.add_argument("--subscribers-timeout", type=float, default=2.0, metavar="S",
                   help="wait at most S s before the first put until a subscriber of every "
                        "replayed key is known (default %(default)g; 0: do not wait)")
    add_quiet_arg(p)
    add_zenoh_args(p, ns=False)
    return p


def remapper(rules: list[str]):
    """A function moving a key from prefix OLD to NEW by the first rule that matches."""
    pairs = []
    for rule in rules:
        old, sep, new = rule.partition("=")
        if not sep or not old.strip("/") or not new.strip("/"):
            raise SystemExit(f"track-replay: --remap wants OLD=NEW (two key prefixes), got "
                             f"{rule!r}")
        pairs.append((old.strip("/"), new.strip("/")))

    def remap(key: str) -> str:
        for old, new in pairs:
            if key == old or key.startswith(old + "/"):
                return new + key[len(old):]
        return key

    return remap


def select(rec: Recording, only: list[str], feed: bool) -> dict[int, Channel]:
    """The channels to replay."""
    pick = [zenoh.KeyExpr(k) for k in only]
    ns = rec.namespace
    if feed:
        if ns is None:
            raise SystemExit("track-replay: --feed needs the recording's namespace, and this "
                             "file names none; use --only")
        inputs = [zenoh.KeyExpr(f"{ns}/{k}") for k in INPUTS]
    out = {}
    for cid, ch in rec.channels.items():
        ke = zenoh.KeyExpr(ch.key)
        if pick and not any(k.includes(ke) for k in pick):
            continue
        if feed and not any(k.includes(ke) for k in inputs):
            continue
        out[cid] = ch
    return out


def holds_inputs(channels: dict[int, Channel], ns: str | None) -> bool:
    """Whether the replay holds service inputs of namespace `ns` (before remapping)."""
    if ns is None:
        return False
    kes = [zenoh.KeyExpr(f"{ns}/{k}") for k in INPUTS[:4]]
    return any(k.includes(zenoh.KeyExpr(ch.key)) for ch in channels.values() for k in kes)


def await_subscribers(session: zenoh.Session, keys: list[zenoh.KeyExpr], timeout: float
                      ) -> int:
    """Wait at most `timeout` s until a subscriber of every key of `keys` is known to the
    session (Zenoh's matching status); the number of keys that have one."""
    if timeout <= 0 or not keys:
        return 0
    cond = threading.Condition()
    pubs = [session.declare_publisher(k) for k in keys]
    listeners = [p.declare_matching_listener(lambda _: _notify(cond)) for p in pubs]
    try:
        with cond:
            cond.wait_for(lambda: all(p.matching_status.matching for p in pubs), timeout)
        return sum(p.matching_status.matching for p in pubs)
    finally:
        for x in (*listeners, *pubs):
            x.undeclare()


def _notify(cond: threading.Condition) -> None:
    with cond:
        cond.notify_all()


def replay(session: zenoh.Session, rec: Recording, channels: dict[int, Channel],
           remap, speed: float | None, quiet: bool) -> int:
    """Publish the samples of `channels`; `speed` None: as fast as possible. Returns the
    number published."""
    block = zenoh.CongestionControl.BLOCK
    targets = {cid: (zenoh.KeyExpr(remap(ch.key)), zenoh.Encoding(ch.encoding or
                                                                   "zenoh/bytes"))
               for cid, ch in channels.items()}
    put, delete = session.put, session.delete
    total = sum(ch.count for ch in channels.values())
    progress = bar(total=total, desc="replaying", unit=" samples", quiet=quiet)
    sent, log0, wall0 = 0, None, time.monotonic()
    pending = 0
    try:
        for ch, s in rec.samples(set(channels)):
            if speed is not None:
                if log0 is None:
                    log0 = s.log_time
                delay = wall0 + (s.log_time - log0) / 1e9 / speed - time.monotonic()
                if delay > 0:
                    time.sleep(delay)  # pacing to the recorded times is the point here
            ke, enc = targets[ch.id]
            if s.kind == "delete":
                delete(ke, congestion_control=block)
            else:
                put(ke, s.payload, encoding=enc, congestion_control=block)
            sent += 1
            pending += 1
            if pending >= 1024:
                progress.update(pending)
                pending = 0
    finally:
        progress.update(pending)
        progress.close()
    return sent


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    on_signals(interrupt=True)
    if args.plot:
        need("matplotlib", "plot", "track-replay --plot")
    if args.speed <= 0:
        raise SystemExit("track-replay: --speed must be > 0")
    remap = remapper(args.remap)
    with open(args.file, "rb") as stream:
        try:
            rec = Recording(stream)
        except Exception as exc:  # mcap raises several types for a file it cannot read
            raise SystemExit(f"track-replay: cannot read {args.file}: {exc}") from None
        channels = select(rec, args.only, args.feed)
        if not channels:
            raise SystemExit("track-replay: nothing to replay (no recorded key matches)")
        if args.plot:
            from zenoh_track.clients.record.recording_plot import plot

            plot(args.file, args.plot, set(channels))
            print(f"track-replay: {args.plot} drawn from {args.file}", flush=True)
            return
        ns = rec.namespace
        trackers = args.trackers if args.trackers is not None else int(
            holds_inputs(channels, ns))
        target = Keys(remap(ns) if ns else "track")
        with open_session(args, block=True, log=True) as session:  # BLOCK puts wait: never drop
            if trackers and not wait_for_tracker(session, target, trackers):
                sys.exit(f"track-replay: no tracker alive on '{target.ns}' after 30 s "
                         "(start track-service, or pass --trackers 0)")
            keys = [zenoh.KeyExpr(k) for k in sorted({remap(ch.key) for ch in channels.values()})]
            await_subscribers(session, keys, args.subscribers_timeout)
            start = time.monotonic()
            try:
                n = replay(session, rec, channels, remap,
                           None if args.fast else args.speed, args.quiet)
            except KeyboardInterrupt:
                return
            print(f"track-replay: {n} samples on {len(channels)} channels in "
                  f"{time.monotonic() - start:.2f} s", flush=True)
            if trackers and not delivered(session, target, trackers, args.receipt_timeout):
                sys.exit(f"track-replay: fewer than {trackers} tracker(s) confirmed receipt")


if __name__ == "__main__":
    main()
