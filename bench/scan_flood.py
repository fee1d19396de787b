"""Batched scans put as fast as the service takes them (bench/bench_capacity.py
--scan-flood [N]): rows applied per second and frames per second meanwhile.

For each run a fresh service with no flags on a free loopback port, a feed of `track-
feed swarm --targets N --duration S-1 --sectors 1 --batched` (S scans of N rows,
`scan/<sensor>`, put with congestion control BLOCK as fast as the service reads them),
and in this process subscribers of `<ns>/frame` and `<ns>/scan/*` and a status poller
(every 50 ms), once the status says the compiled kernels serve (`kernels`: the steady
speed, not the first second's NumPy forms). The scans reach the service's channel at
once (20 messages); a status query waits behind them and is answered when the worker has
applied what came before it. Rows applied per second: S x N over the span from the first
scan's arrival here to the first status answer counting them all; frames per second: the
frames received over the same span, and `frames_published` likewise. With --full-
listener a subscriber of `<ns>/tracks/**` in another process (bench/full_listener.py)
gets every state too.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import Keys, free_port, peer_config, unpack, wait_for_tracker  # noqa: E402

POLL = 0.05  # s between two status queries


def kernels(session: zenoh.Session, keys: Keys) -> str:
    """The status field `kernels` (a service before it: "compiled")."""
    for r in session.get(keys.status, timeout=5.0):
        if r.ok is not None:
            return str(unpack(r.ok.payload.to_bytes()).get("kernels", "compiled"))
    return "compiling"


def flood_one(n: int, scans: int, full: bool, log: Any) -> dict[str, Any]:
    ns = f"flood{time.monotonic_ns() % 10**9}"
    keys, ep = Keys(ns), f"tcp/127.0.0.1:{free_port()}"
    py = sys.executable
    svc = subprocess.Popen([py, "-m", "zenoh_track", "--clock", "realtime", "-l", ep, "--ns",
                            ns], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                           text=True)
    session = zenoh.open(peer_config(ep))
    listener = None
    polls: list[tuple[float, int, int]] = []  # (answered, meas_accepted, frames_published)
    frames: list[float] = []
    arrivals: list[float] = []
    halt = threading.Event()
    try:
        if not wait_for_tracker(session, keys, 1, timeout=60):
            raise RuntimeError(f"the service did not come up: {stop(svc)[-500:]}")
        sub = session.declare_subscriber(keys.frame, zenoh.handlers.Callback(
            lambda s: frames.append(time.time()), indirect=False))
        scans_in = session.declare_subscriber(keys.scan("*"), zenoh.handlers.Callback(
            lambda s: arrivals.append(time.time()), indirect=False))
        if full:
            listener = subprocess.Popen([py, str(ROOT / "bench" / "full_listener.py"), ep, ns,
                                         "/dev/null"], cwd=ROOT, stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True)
            listener.stdout.readline()  # type: ignore[union-attr]  # ready

        def poll() -> None:
            while not halt.is_set():
                for r in session.get(keys.status, timeout=5.0):
                    if r.ok is not None:
                        s = unpack(r.ok.payload.to_bytes())
                        polls.append((time.time(), s["meas_accepted"], s["frames_published"]))
                halt.wait(POLL)

        end = time.time() + 120  # the compiled kernels loaded: the service's steady speed
        while time.time() < end and kernels(session, keys) == "compiling":
            time.sleep(0.1)
        poller = threading.Thread(target=poll, daemon=True)
        poller.start()
        time.sleep(1.0)
        feed = [py, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets", str(n),
                "--duration", str(scans - 1), "--sectors", "1", "--batched", "-e", ep,
                "--ns", ns]
        subprocess.run(feed, cwd=ROOT, capture_output=True, text=True, timeout=600)
        want, end = n * scans, time.time() + 60
        while (not polls or polls[-1][1] < want) and time.time() < end:
            time.sleep(POLL)
        time.sleep(0.5)
        halt.set()
        poller.join(timeout=10)
        sub.undeclare()
        scans_in.undeclare()
    finally:
        halt.set()
        if listener is not None:
            try:
                listener.communicate("stop\n", timeout=60)
            except subprocess.TimeoutExpired:
                stop(listener)
        session.close()
        stop(svc)
    total = polls[-1][1] if polls else 0
    done = next((p for p in polls if p[1] >= n * scans), None)
    if done is None or not arrivals:
        return {"total": total, "rate": float("nan"), "frames": float("nan"),
                "published": float("nan"), "span": 0.0}
    t0, (t1, _, f1) = min(arrivals), done
    f0 = max((p[2] for p in polls if p[0] <= t0), default=0)  # published before the first
    got = np.array(frames)
    inside = got[(got >= t0) & (got < t1)]
    return {"total": total, "rate": total / (t1 - t0), "span": t1 - t0,
            "frames": len(inside) / (t1 - t0), "published": (f1 - f0) / (t1 - t0),
            "gap_ms": float(np.diff(inside).max() * 1e3) if len(inside) > 1 else float("nan")}


def scan_flood(args: argparse.Namespace, log: Any) -> None:
    n, scans = args.scan_flood[0] if args.scan_flood else 10_000, 20
    reps = max(1, args.repeat)
    log(f"scan flood: {scans} batched scans of {n} rows (scan/<sensor>) put as fast as the "
        f"service (no flags) takes them; {reps} run(s)"
        + ("; a tracks/** subscriber in another process" if args.full_listener else ""))
    log(f"{'run':>4} {'rows':>8} {'rows/s':>9} {'span s':>7} {'frames/s':>9} "
        f"{'published/s':>12} {'max gap ms':>10}")
    for k in range(reps):
        r = flood_one(n, scans, args.full_listener, log)
        log(f"{k + 1:>4} {r['total']:>8} {r['rate']:>9.0f} {r['span']:>7.2f} "
            f"{r['frames']:>9.1f} {r['published']:>12.1f} {r.get('gap_ms', float('nan')):>10.0f}")
    log("  rows/s: the rows over the span from the first scan's arrival here to the first "
        "status answer counting them all (the query waits behind the scans); frames/s: "
        "frames received here over that span (published/s: the status frames_published); "
        "max gap: the longest wait between two frames received in it")
