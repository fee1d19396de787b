"""CPU of the service's worker per single labelled message, against the echo's, in one
process (bench/bench_capacity.py --single-cost N).

A `TrackService` (no flags: the default IMM) on a real Zenoh session, a consumer process
subscribed to `<ns>/tracks/**` (so every state is put, as in the throughput benchmark),
and N swarm targets' single radar messages handed to the worker's `_process` in batches
of `adapter.ingest.MAX_BATCH`, as the worker takes them from its channel in a burst: thread CPU time
per message over scans 2 to 5. The echo's work on the same messages (decode, a small
reply put, bench/echo.py) is timed the same way in the same run. Zenoh's receive path
is outside both figures (the same for both processes); the put is inside both.
"""

from __future__ import annotations

import subprocess
import sys
import time
from typing import Any

import numpy as np
import zenoh

CONSUMER = """
import sys, zenoh
from zenoh_track.wire import peer_config
s = zenoh.open(peer_config("{ep}"))
n = [0]
sub = s.declare_subscriber("{key}", zenoh.handlers.Callback(
    lambda x: n.__setitem__(0, n[0] + 1), indirect=False))
print("ready", flush=True)
sys.stdin.readline()
print(n[0], flush=True)
"""


def start_consumer(ep: str, key: str) -> subprocess.Popen:
    """A process subscribed to `key` through `ep`, counting what it gets (`CONSUMER`)."""
    return subprocess.Popen([sys.executable, "-c", CONSUMER.format(ep=ep, key=key)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def compiled() -> None:
    """The compiled kernels loaded here, as a running service has them (the NumPy forms
    serve only until they are: `estimation/jit.py`)."""
    try:
        from zenoh_track.estimation import imm_jit, jit
        from zenoh_track.tracking import frame
    except ImportError:  # a tree before jit.py: the kernels are compiled at import
        return
    try:
        from zenoh_track.tracking.compiled import KERNELS
    except ImportError:  # a tree before the list
        KERNELS = (imm_jit, frame)
    jit.prepare(KERNELS, wait=True)


def listened_service(session: Any, keys: Any, consumer: subprocess.Popen) -> Any:
    """A `TrackService` (no flags, realtime, its worker not started) on `session`, once
    the consumer is up and the service sees its subscription."""
    from zenoh_track.adapter import TrackService
    from zenoh_track.tracking.tracker import Tracker

    compiled()
    consumer.stdout.readline()  # type: ignore[union-attr]
    svc = TrackService(session, keys, Tracker.from_config(), clock="realtime")
    end = time.monotonic() + 10
    while svc.out.track_listeners.none and time.monotonic() < end:
        svc.out.track_listeners.look()
        time.sleep(0.05)
    return svc


def single_cost(sizes: list[int], log: Any, scans: int = 5) -> None:
    from zenoh_track.adapter.ingest import MAX_BATCH, Singles
    from zenoh_track.wire import Keys, free_port, listen_config, pack, unpack

    clock = time.thread_time
    log(f"single-message cost: the worker's CPU per message (no flags, batches of "
        f"{MAX_BATCH}, a consumer of tracks/**) against the echo's, scans 2-{scans}")
    log(f"{'N':>8} {'service us':>10} {'echo us':>8} {'x echo':>7} {'answered':>9}")
    for n in sizes:
        ep = f"tcp/127.0.0.1:{free_port()}"
        session = zenoh.open(listen_config(ep))
        keys = Keys(f"sc{n}")
        consumer = start_consumer(ep, keys.tracks("**"))
        try:
            svc = listened_service(session, keys, consumer)
            rng = np.random.default_rng(0)
            r, az = rng.uniform(5e3, 8e4, n), rng.uniform(-3, 3, n)
            t0 = time.time()
            ours, echo = [], []
            for k in range(scans):
                items = Singles.joined([Singles.one(keys.meas("radar1", f"swarm-{i:06d}"), pack(
                    {"t": t0 + k, "r": float(r[i]) + 10 * k, "az": float(az[i]), "el": 0.1,
                     "sr": 20.0, "saz": 0.003, "sel": 0.003, "seq": k * n + i}), time.time())
                         for i in range(n)])
                c0 = clock()
                for lo in range(0, n, MAX_BATCH):
                    svc._process([Singles(items.keys[lo:lo + MAX_BATCH],
                                          items.payloads[lo:lo + MAX_BATCH],
                                          items.walls[lo:lo + MAX_BATCH])])
                ours.append(clock() - c0)
                c0 = clock()  # the echo: decode, reply {t, id} on tracks/<target>
                for key, payload in zip(items.keys, items.payloads, strict=True):
                    msg = unpack(payload)
                    target = key.rsplit("/", 1)[1]
                    session.put(keys.tracks(target), pack({"t": msg["t"], "id": target}),
                                congestion_control=zenoh.CongestionControl.BLOCK)
                echo.append(clock() - c0)
            time.sleep(1.0)
            consumer.stdin.write("\n")  # type: ignore[union-attr]
            consumer.stdin.flush()  # type: ignore[union-attr]
            got = int(consumer.stdout.readline())  # type: ignore[union-attr]
            a, b = (float(np.median(x[1:])) / n * 1e6 for x in (ours, echo))
            log(f"{n:>8} {a:>10.1f} {b:>8.1f} {a / b:>7.2f} {got:>9}")
            svc.out.close()
        finally:
            consumer.kill()
            consumer.wait()
            session.close()
    log("  service us: the worker's thread CPU per message (check, IMM update, tracks/ "
        "body and put); echo us: bench/echo.py's work per message (decode, small reply "
        "put); answered: tracks/ messages the consumer received (service and echo)")
    step_cost(log)


def step_cost(log: Any, tracks: int = 10_000, sizes: tuple[int, ...] = (1, 64, 312, 1024),
              reps: int = 20) -> None:
    """CPU of one pass of labelled rows (`Tracker.step`, the default IMM) at
    `tracks` tracks, by the rows in the pass: the fixed cost of a worker step, which
    decides the latency of small batches (a sector of 10,000 targets in 32 is 312)."""
    from zenoh_track.estimation.measurements import MeasurementBatch
    from zenoh_track.tracking.batches import Labelled
    from zenoh_track.tracking.tracker import Tracker
    from zenoh_track.wire import Measurement

    compiled()
    rng = np.random.default_rng(0)
    r, az = rng.uniform(5e3, 8e4, tracks), rng.uniform(-3, 3, tracks)
    ids = [f"swarm-{i:06d}" for i in range(tracks)]

    def batch(t: float, k: int) -> MeasurementBatch:
        return MeasurementBatch.of([Measurement(
            "r", ids[i], t, 3, True, (float(r[i]) + 10 * t, float(az[i]), 0.1),
            (20.0, 0.003, 0.003), (0.0, 0.0, 0.0), None) for i in range(k)], 3)

    tracker = Tracker.from_config()
    for t in (0.0, 1.0):
        tracker.step(Labelled(["r"] * tracks, ids, batch(t, tracks)), want=None)
    log(f"one pass of k rows at {tracks} tracks (Tracker.step, IMM), CPU, median of {reps}:")
    t = 2.0
    for k in sizes:
        spent = []
        for _ in range(reps):
            b, t = batch(t, k), t + 0.01
            c0 = time.thread_time()
            tracker.step(Labelled(["r"] * k, ids[:k], b), want=None)
            spent.append(time.thread_time() - c0)
        ms = float(np.median(spent)) * 1e3
        log(f"  k = {k:>5}: {ms:6.2f} ms per pass, {ms * 1e3 / k:7.1f} us per row")
