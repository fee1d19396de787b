"""Late joiners: time from a client's session opening to its first complete picture.

A service holds N tracks (a swarm feed); then, several times, a new client session joins
and times how long until it has every track: by subscription alone (`display/**`, or
`frame`), by subscription plus the query of the latest instant (`get display/**`,
`get frame`; docs/operations.md), or by the query alone (without the subscription's
stream competing for this process's Python thread). Realtime: frames go on at 30 Hz;
lockstep: the feed has finished and the picture is paused, so a subscription alone gets
nothing.

    python bench/bench_late_join.py --targets 1000 --joins 5
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import Keys, decode_frame, free_port, peer_config, unpack  # noqa: E402

HOWS = ("display", "display+get", "get display", "frame", "frame+get", "get frame")


def wait_tracks(session: zenoh.Session, keys: Keys, n: int, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for r in session.get(keys.status, timeout=5):
            if r.ok is not None and unpack(r.ok.payload.to_bytes())["tracks"] >= n:
                return
        time.sleep(0.2)
    raise SystemExit("the service did not reach the targets")


def join(endpoint: str, keys: Keys, n: int, how: str, limit: float) -> float | None:
    """Seconds from opening a session to holding all n tracks (None: not within limit)."""
    t0 = time.monotonic()
    s = zenoh.open(peer_config(endpoint))
    ids: set[str] = set()
    done = threading.Event()
    lock = threading.Lock()

    def add(new: set[str]) -> None:
        with lock:
            ids.update(new)
            if len(ids) >= n:
                done.set()

    def on_display(sample) -> None:
        add({str(sample.key_expr).rsplit("/", 1)[1]})

    def on_frame(sample) -> None:
        rows = decode_frame(unpack(sample.payload.to_bytes()))
        if len(rows) >= n:
            add({r["id"] for r in rows})

    try:
        if how.startswith("get "):  # the query alone, no subscription
            key = keys.space("display") if how == "get display" else keys.frame
            on = on_display if how == "get display" else on_frame
            for r in s.get(key, timeout=10):
                if r.ok is not None:
                    on(r.ok)
        elif how.startswith("display"):
            s.declare_subscriber(keys.space("display"), on_display)
            if how.endswith("+get"):
                for r in s.get(keys.space("display"), timeout=10):
                    if r.ok is not None:
                        on_display(r.ok)
        else:
            s.declare_subscriber(keys.frame, on_frame)
            if how.endswith("+get"):
                for r in s.get(keys.frame, timeout=10):
                    if r.ok is not None:
                        on_frame(r.ok)
        ok = done.wait(limit)
        return time.monotonic() - t0 if ok else None
    finally:
        s.close()


def run(clock: str, targets: int, joins: int) -> dict[str, list[float | None]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys("latebench")
    svc = subprocess.Popen([sys.executable, "-m", "zenoh_track", "-l", endpoint, "--ns", keys.ns,
                            "--clock", clock], stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    feed = None
    s = None
    try:
        time.sleep(1.0)
        s = zenoh.open(peer_config(endpoint))
        args = ["--duration", "3"] if clock == "lockstep" else ["--duration", "3600",
                                                                 "--realtime"]
        feed = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm",
                                 "--targets",
                                 str(targets), *args, "-e", endpoint, "--ns", keys.ns],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if clock == "lockstep":
            feed.wait(timeout=300)
        wait_tracks(s, keys, targets)
        out: dict[str, list[float | None]] = {}
        for how in HOWS:
            out[how] = [join(endpoint, keys, targets, how, 3.0) for _ in range(joins)]
        return out
    finally:
        if s is not None:
            s.close()
        stop(feed)
        stop(svc)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--targets", type=int, default=1000)
    p.add_argument("--joins", type=int, default=5)
    args = p.parse_args()
    print(f"time to the first complete picture of {args.targets} tracks, median of "
          f"{args.joins} joins (ms; '-' = not within 3 s)")
    print(f"{'clock':<10}{'display/**':>12}{'+ get':>10}{'get only':>10}{'frame':>10}"
          f"{'+ get':>10}{'get only':>10}")
    for clock in ("realtime", "lockstep"):
        res = run(clock, args.targets, args.joins)
        cells = []
        for how in HOWS:
            got = [v for v in res[how] if v is not None]
            cells.append(f"{statistics.median(got) * 1e3:.0f}" if len(got) == len(res[how])
                         else f"- ({len(got)}/{len(res[how])})")
        print(f"{clock:<10}" + "".join(f"{c:>10}" if i else f"{c:>12}"
                                      for i, c in enumerate(cells)), flush=True)


if __name__ == "__main__":
    main()
