"""Parts of the capacity benchmark (bench/bench_capacity.py): throughput against the echo
floor, and the cost of a frame.

`throughput`: for each contender a fresh process on a free loopback port (the echo floor,
bench/echo.py; the service with no flags; the service tuned), a feed of N swarm targets
as fast as it can (`track-feed swarm --duration D`, no --realtime, each second's
measurements in one burst: --sectors 1), and this process subscribing `<ns>/tracks/**`
(so that the service puts every reply: it puts `tracks/<id>` only for subscribers) and
counting the replies in a callback. Rate = replies / (last - first arrival); every
measurement must be answered. `CPU us`: the contender's process CPU (all its threads,
from /proc) per message from the feed's start to the last reply: on this CPU-bound
2-core machine the ratio follows it. The contenders run one after the other in the same run,
and the ratio to the echo floor is printed. With --batched the feed sends scans
(`scan/<sensor>`, one per second of 10,000 rows), which the echo does not read: the
batched line is the service alone.

`frame_cost`: the worker's CPU per frame at N tracks of the default IMM, in this process
on a real Zenoh session: the empty step (coast, delete), the snapshot (every track drawn
at the instant) and `Publisher.frame` (check, `pack_frame`, put), as
`Frames.publish` runs them, with a sector of the tracks updated between
frames.
"""

from __future__ import annotations

import argparse
import math
import os
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

import procstat  # noqa: E402  # bench/procstat.py
from scan_flood import kernels  # noqa: E402  # bench/scan_flood.py
from single_cost import compiled  # noqa: E402  # bench/single_cost.py

from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import Keys, free_port, listen_config, peer_config, wait_for_tracker  # noqa: E402

TRACKS_BODY = 1031  # bytes of a 3-D IMM track's `tracks/` body (encode.pack_tracks)


class Replies:
    """Counts `tracks/` replies on Zenoh's receive thread: count, first and last arrival."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.n, self.first, self.last = 0, None, None
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(
            keys.tracks("**"), zenoh.handlers.Callback(self._on, indirect=False))

    def _on(self, sample: Any) -> None:
        now = time.monotonic()
        if sample.kind != zenoh.SampleKind.PUT:
            return
        with self.lock:
            self.n += 1
            self.first = now if self.first is None else self.first
            self.last = now


def cpu_seconds(pid: int) -> float | None:
    """CPU time (user + system, every thread) of a process so far; None without Linux's
    /proc."""
    try:
        return procstat.cpu_seconds(pid)
    except (OSError, ValueError, IndexError):
        return None


def one(cmd: list[str], n: int, scans: int, batched: bool, log: Any) -> dict[str, Any]:
    """Start `cmd` (a tracker on ENDPOINT/NS), flood it, count its replies."""
    ns = f"thr{os.getpid()}{time.monotonic_ns() % 100000}"
    keys, endpoint = Keys(ns), f"tcp/127.0.0.1:{free_port()}"
    cmd = [c.replace("ENDPOINT", endpoint).replace("NS", ns) for c in cmd]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    session = zenoh.open(peer_config(endpoint))
    try:
        if not wait_for_tracker(session, keys, 1, timeout=60):
            raise RuntimeError(f"{cmd} did not come up: {stop(proc)[-500:]}")
        end = time.monotonic() + 120  # the compiled kernels loaded: the steady speed
        while time.monotonic() < end and kernels(session, keys) == "compiling":
            time.sleep(0.1)
        replies = Replies(session, keys)
        time.sleep(0.5)
        feed = [sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets",
                str(n),
                "--duration", str(scans - 1), "--sectors", "1", "-e", endpoint, "--ns", ns]
        t0, cpu0 = time.monotonic(), cpu_seconds(proc.pid)
        done = subprocess.run(feed + (["--batched"] if batched else []), cwd=ROOT,
                              capture_output=True, text=True, timeout=600)
        sent_s = time.monotonic() - t0
        want = n * scans
        end = time.monotonic() + 60
        while replies.n < want and time.monotonic() < end:
            time.sleep(0.05)
        span = (replies.last or 0) - (replies.first or 0)
        cpu1 = cpu_seconds(proc.pid)  # the flood's CPU: from the feed's start to the last reply
        cpu = (cpu1 - cpu0) / want * 1e6 if cpu0 is not None and cpu1 is not None else math.nan
        return {"answered": replies.n, "sent": want, "rate": replies.n / span if span else 0,
                "feed_s": sent_s, "feed_rc": done.returncode, "cpu_us": cpu}
    finally:
        session.close()
        stop(proc)


def throughput(args: argparse.Namespace, log: Any) -> None:
    n, scans = args.throughput, max(3, int(args.duration))
    py = sys.executable
    service = [py, "-m", "zenoh_track", "--clock", "realtime", "-l", "ENDPOINT", "--ns", "NS"]
    runs = [("echo floor (bench/echo.py)", [py, "bench/echo.py", "-l", "ENDPOINT", "--ns",
                                             "NS"], False),
            *([("echo, replies of a tracks/ body's size", [
                py, "bench/echo.py", "-l", "ENDPOINT", "--ns", "NS", "--reply-bytes",
                str(TRACKS_BODY)], False)] if getattr(args, "echo_body", False) else []),
            ("service, no flags", service, False),
            ("service, --filter cv --no-display-keys", service + ["--filter", "cv",
                                                                  "--no-display-keys"], False),
            ("service, no flags, batched scans", service, True)]
    reps = max(1, getattr(args, "repeat", 1))
    log(f"throughput: swarm of {n} targets, {scans} scans of {n} as fast as the feed can "
        f"(--sectors 1); replies on tracks/** counted here"
        + (f"; the contenders in turn {reps} times, medians" if reps > 1 else ""))
    log(f"{'contender':<44} {'answered':>9} {'of':>9} {'per s':>8} {'x echo':>7} "
        f"{'CPU us':>6}" + ("  rates of each round (x echo)" if reps > 1 else ""))
    rounds = [[one(cmd, n, scans, batched, log) for _, cmd, batched in runs]
              for _ in range(reps)]  # in turn: a change of the machine's load hits all
    floor = float(np.median([rs[0]["rate"] for rs in rounds]))
    for k, (name, _, _) in enumerate(runs):
        rates = [rs[k]["rate"] for rs in rounds]
        rate = float(np.median(rates))
        cpu = float(np.median([rs[k]["cpu_us"] for rs in rounds]))
        answered = min(rs[k]["answered"] for rs in rounds)
        log(f"{name:<44} {answered:>9} {rounds[0][k]['sent']:>9} {rate:>8.0f} "
            f"{rate / floor:>7.2f} {cpu:>6.1f}"
            + ("  " + " ".join(f"{x:.0f} ({x / rs[0]['rate']:.2f})"
                               for x, rs in zip(rates, rounds, strict=True))
               if reps > 1 else ""))
    log("  CPU us: the contender's process CPU (every thread) per message from the feed's "
        "start to the last reply (median of the rounds); (x echo): each round's rate "
        "against that round's echo")


FRAME_WATCHER = """
import sys, zenoh
from zenoh_track.wire import peer_config
s = zenoh.open(peer_config(sys.argv[1]))
n = [0]
sub = s.declare_subscriber(sys.argv[2], zenoh.handlers.Callback(
    lambda x: n.__setitem__(0, n[0] + 1), indirect=False))
print("ready", flush=True)
sys.stdin.readline()
print(n[0], flush=True)
"""


def frame_cost(sizes: list[int], log: Any, frames: int = 60) -> None:
    """The worker's CPU (thread time) per frame at N tracks of the default IMM, as
    `Frames.publish` spends it on a real Zenoh session: the empty step that
    coasts and deletes (`tracker.step(Instant(t))`), the snapshot (every track drawn at
    the instant) and `Publisher.frame` (the finiteness check, `pack_frame`, the put). The
    tracks are a swarm updated in three passes (as single_cost.step_cost makes them), and
    between two frames a thirtieth of them (a sector of azimuth at 1 Hz: rows scattered
    over the store) takes a measurement, untimed, as in service: the frame's work
    includes what those updates leave for it.
    Medians over `frames` frames with nobody subscribed to `frame`, then as many with a
    subscriber in another process (Zenoh's put then sends the body)."""
    from zenoh_track.adapter import TrackService
    from zenoh_track.tracking.batches import Instant, Labelled
    from zenoh_track.tracking.tracker import Tracker

    clock = time.thread_time
    log(f"frame cost: the worker's CPU per frame (thread time), default IMM, tracks "
        f"updated; a thirtieth of them updated between frames; medians of {frames} frames, "
        "ms")
    log(f"{'':>8} {'no subscriber':^36} {'a subscriber of frame':^28}")
    log(f"{'N':>8} {'step':>7} {'snapshot':>9} {'publish':>8} {'total':>8} {'publish':>9} "
        f"{'total':>8} {'% of 33 ms':>10}")
    compiled()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(listen_config(endpoint))
    try:
        for n in sizes:
            rng = np.random.default_rng(0)
            r, az = rng.uniform(5e3, 8e4, n), rng.uniform(-3, 3, n)
            ids = [f"swarm-{i:06d}" for i in range(n)]
            tracker = Tracker.from_config()
            for t in (0.0, 1.0, 2.0):
                tracker.step(Labelled(["r"] * n, ids, _swarm_batch(t, r, az, range(n))),
                             want=None)
            keys = Keys(f"fc{os.getpid()}{n}")
            svc = TrackService(session, keys, tracker, clock="realtime")
            sector = max(1, n // 30)
            by_azimuth = np.argsort(az)  # a sector's targets: rows all over the store
            spent: list[list[tuple[float, float, float]]] = [[], []]
            watcher = None
            try:
                for k in range(2 * frames + 2):
                    if k == frames + 1:  # the second half: a display watches
                        watcher = subprocess.Popen(
                            [sys.executable, "-c", FRAME_WATCHER, endpoint, keys.frame],
                            cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
                        watcher.stdout.readline()  # type: ignore[union-attr]
                        end = time.monotonic() + 10
                        while (not svc.out.pub_frame.matching_status.matching
                               and time.monotonic() < end):
                            time.sleep(0.01)
                    t = 3.0 + k / 30
                    lo = (k * sector) % n
                    rows = np.sort(by_azimuth[lo:lo + sector]).tolist()
                    tracker.step(Labelled(["r"] * len(rows), [ids[i] for i in rows],
                                          _swarm_batch(t - 0.01, r, az, rows)), want=None)
                    c0 = clock()
                    svc.out.deleted(tracker.step(Instant(t)).deleted)  # as Frames.publish
                    c1 = clock()
                    snap = tracker.snapshot(t, detail=False)
                    c2 = clock()
                    svc.out.frame(t, snap)
                    c3 = clock()
                    if k and k != frames + 1:  # not the first of each half
                        spent[k > frames].append((c1 - c0, c2 - c1, c3 - c2))
                    if watcher is not None:
                        time.sleep(1 / 30)  # the link drains as between two real frames
            finally:
                if watcher is not None:
                    watcher.kill()
                    watcher.wait()
                svc.out.close()
            a, b, c = (float(np.median(x)) * 1e3 for x in zip(*spent[0], strict=True))
            total = float(np.median([sum(x) for x in spent[0]])) * 1e3
            c2 = float(np.median([x[2] for x in spent[1]])) * 1e3
            total2 = float(np.median([sum(x) for x in spent[1]])) * 1e3
            log(f"{n:>8} {a:>7.2f} {b:>9.2f} {c:>8.2f} {total:>8.2f} {c2:>9.2f} "
                f"{total2:>8.2f} {total2 / (1e3 / 30) * 100:>10.1f}")
    finally:
        session.close()
    log("  step: tracker.step(Instant(t)) (coast, delete); snapshot: tracker.snapshot(t); "
        "publish: Publisher.frame (check, pack_frame, put); total: median of the sums; "
        "% of the display period with a subscriber")


def _swarm_batch(t: float, r: np.ndarray, az: np.ndarray, rows: Any) -> Any:
    """Radar measurements of swarm targets `rows` at time t (moving 10 m/s outwards)."""
    from zenoh_track.estimation.measurements import MeasurementBatch
    from zenoh_track.wire import Measurement

    return MeasurementBatch.of([Measurement(
        "r", f"swarm-{i:06d}", t, 3, True, (float(r[i]) + 10 * t, float(az[i]), 0.1),
        (20.0, 0.003, 0.003), (0.0, 0.0, 0.0), None) for i in rows], 3)


def scan_cost(sizes: list[int], log: Any, rows: int = 10_000) -> None:
    """CPU time of the worker's parts for batched scans, in this process: a swarm of N
    targets reported in scans of `rows` rows (N / rows sectors per turn, one turn per
    second); per row the check of the columns (`parse_scan_columns`, `MeasurementBatch.
    of_scan`) and the one-pass application (`Tracker.step`, the default
    IMM), against the filter core (`filters.cmkf_step`, CV) on as many rows in the same
    run; the frame at N tracks (snapshot + pack_frame); and what one core could then
    sustain: measurements per second with 30 frames per second."""
    from zenoh_track import defaults
    from zenoh_track.adapter.encode import pack_frame
    from zenoh_track.clients.feeds import scenarios
    from zenoh_track.estimation.filters import cmkf_step
    from zenoh_track.estimation.measurements import MeasurementBatch
    from zenoh_track.tracking.batches import Labelled
    from zenoh_track.tracking.tracker import Tracker
    from zenoh_track.wire import pack, parse_scan, parse_scan_columns

    clock = time.process_time
    log(f"scan cost: swarm of N targets in scans of {rows} rows (N / {rows} sectors per "
        "turn), CPU time of this process, turns 0-1 warm-up, turn 2 measured")
    log(f"{'N':>8} {'check':>7} {'apply':>7} {'core':>6} {'apply/core':>10} {'frame':>7} "
        f"{'meas/s/core':>12} {'records':>8} {'x':>5}")
    compiled()
    for n in sizes:
        tracker, ref = Tracker.from_config(), Tracker.from_config()
        turns: list[list[bytes]] = [[], [], []]
        for sent, sec in scenarios.swarm_sectors(n, 0, 2.0, sectors=max(1, n // rows)):
            msg = {"ids": [sec.names[i] for i in sec.idx.tolist()], "t": sec.t.tobytes(),
                   "r": sec.r.tobytes(), "az": sec.az.tobytes(), "el": sec.el.tobytes(),
                   "sr": sec.sr, "saz": sec.sa, "sel": sec.sa}
            turns[min(2, int(sent - 1e-9))].append(pack(msg))
        check = apply = 0.0
        count = 0
        for k, turn in enumerate(turns):
            for payload in turn:
                t0 = clock()
                cols = parse_scan_columns("radar1", payload, defaults.NOISE)
                batch = MeasurementBatch.of_scan(cols)
                t1 = clock()
                tracker.step(Labelled(["radar1"] * len(cols.ids), cols.ids, batch), want=None)
                t2 = clock()
                if k == 2:
                    check, apply, count = check + t1 - t0, apply + t2 - t1, count + len(cols.ids)
        # records (parse_scan, made columns again) on the same scans, small N only
        records = float("nan")
        if n <= 20_000:
            spent = 0.0
            for k, turn in enumerate(turns):
                for payload in turn:
                    t0 = clock()
                    ref.step(Labelled.of(parse_scan("radar1", payload,
                                                    defaults.NOISE).measurements))
                    if k == 2:
                        spent += clock() - t0
            records = spent / count * 1e6
        arrays = tracker.store.layout(3)
        live = arrays.live()[0][:len(batch)]
        x = np.ascontiguousarray(arrays.x[live][:, :6])
        p = np.ascontiguousarray(arrays.p[live][:, :6, :6])
        dt = np.full(len(batch), 0.5)
        core = min(_timed(clock, cmkf_step, x, p, dt, 2, 3, 1.0, batch)
                   for _ in range(5)) / len(batch) * 1e6
        ids = pack(tracker.snapshot(2.5, detail=False).ids)
        frame_ms = float(np.median([_timed(clock, _frame, tracker, ids, pack_frame)
                                    for _ in range(10)])) * 1e3
        per_row = (check + apply) / count * 1e6
        rate = (1.0 - 30 * frame_ms / 1e3) / per_row * 1e6
        log(f"{n:>8} {check / count * 1e6:>7.2f} {apply / count * 1e6:>7.2f} {core:>6.2f} "
            f"{apply / count * 1e6 / core:>10.1f} {frame_ms:>7.1f} {rate:>12.0f} "
            f"{records:>8.2f} {records / per_row:>5.1f}")
    log("  check, apply: us of CPU per row (the scan's columns checked and made arrays; the "
        "rows applied in one pass, IMM); core: us per row of filters.cmkf_step (CV, the "
        "single-model filter core) on as many rows, same run; frame: ms per frame at N "
        "tracks (every track predicted to the instant + pack_frame); meas/s/core: rows one "
        "core could apply per second beside 30 frames per second; records: us per row of "
        "the record path (parse_scan + Tracker.track, row by row instead of one pass), x: "
        "its ratio to check + apply")


def _timed(clock: Any, fn: Any, *args: Any) -> float:
    t0 = clock()
    fn(*args)
    return clock() - t0


def _frame(tracker: Any, ids: bytes, pack_frame: Any) -> None:
    snap = tracker.snapshot(2.5, detail=False)
    pack_frame(2.5, ids, snap.pos, snap.vel, snap.sigma, snap.codes)


def client_of(endpoint: str, timeout: float = 30.0) -> zenoh.Session:
    """A client session of the router at `endpoint` (multicast scouting off), retried
    while the router is starting."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    end = time.monotonic() + timeout
    while True:
        try:
            return zenoh.open(conf)
        except zenoh.ZError:
            if time.monotonic() > end:
                raise
            time.sleep(0.5)


def scaleout(args: argparse.Namespace, log: Any) -> None:
    """One service against two shards behind a router (the wheel's `track-router`), each
    shard taking the ids ending in even or odd digits (`--meas '<ns>/meas/*/$*0'` ...,
    deploy/README.md); the same flood as `throughput`, replies counted at an observer
    that is a client of the router."""
    n, scans = args.scaleout, max(3, int(args.duration))
    py = sys.executable
    log(f"scale-out: swarm of {n} targets, {scans} scans as fast as the feed can, through "
        "a router; replies on tracks/** counted here")
    log(f"{'deployment':<40} {'answered':>9} {'of':>9} {'per s':>8} {'x one':>6}")
    base = None
    for shards in (1, 2):
        ns = f"sco{os.getpid()}{shards}"
        keys, endpoint = Keys(ns), f"tcp/127.0.0.1:{free_port()}"
        procs = [subprocess.Popen([py, "-m", "zenoh_track.router", "-l", endpoint], cwd=ROOT,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
        session = None
        try:
            session = client_of(endpoint)  # the router is up
            for k in range(shards):
                part = [] if shards == 1 else [
                    a for d in range(k, 10, 2) for a in ("--meas", f"{ns}/meas/*/$*{d}")]
                procs.append(subprocess.Popen(
                    [py, "-m", "zenoh_track", "--clock", "realtime", "--mode", "client", "-e",
                     endpoint, "--ns", ns, "--instance", f"shard{k}", *part], cwd=ROOT,
                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            if not wait_for_tracker(session, keys, shards, timeout=60):
                raise RuntimeError("shards did not come up")
            replies = Replies(session, keys)
            time.sleep(0.5)
            subprocess.run([py, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets",
                           str(n),
                            "--duration", str(scans - 1), "--sectors", "1", "--mode", "client",
                            "-e", endpoint, "--ns", ns, "--trackers", str(shards)],
                           cwd=ROOT, capture_output=True, text=True, timeout=600)
            end = time.monotonic() + 60
            while replies.n < n * scans and time.monotonic() < end:
                time.sleep(0.05)
            span = (replies.last or 0) - (replies.first or 0)
            rate = replies.n / span if span else 0.0
            base = rate if base is None else base
            name = "one service" if shards == 1 else "two shards (even / odd last digit)"
            log(f"{name:<40} {replies.n:>9} {n * scans:>9} {rate:>8.0f} {rate / base:>6.2f}")
        finally:
            if session is not None:
                session.close()
            for proc in reversed(procs):
                stop(proc)
